"""Entry point of the desktop editor: ``python -m x2video_app [SHOT|PROJECT]``."""
import sys


def main(argv=None) -> int:
    import multiprocessing

    multiprocessing.freeze_support()
    from x2video_app.main_window import run  # Qt imported lazily, only when the app starts

    return run(sys.argv[1:] if argv is None else argv)


if __name__ == "__main__":
    sys.exit(main())
