"""Entry point of the desktop editor: ``python -m x2video_app [SHOT|PROJECT]``; ``--selftest [SHOT]`` opens it
offscreen, renders two frames and exits 0 (`x2video_app.tools.selftest`, for checking a bundle)."""
import sys


def main(argv=None) -> int:
    import multiprocessing

    multiprocessing.freeze_support()
    argv = sys.argv[1:] if argv is None else list(argv)
    if len(argv) >= 2 and argv[0] == "--run-module":  # a frozen bundle's `python -m MODULE ARGS` (x2video_app.state.demo uses it)
        import runpy

        sys.argv = argv[1:]
        runpy.run_module(argv[1], run_name="__main__", alter_sys=True)
        return 0
    if "--selftest" in argv:
        from x2video_app.tools.selftest import run as selftest  # Qt imported lazily, only when the app starts

        return selftest([a for a in argv if a != "--selftest"])
    from x2video_app._qt.launch import run  # Qt imported lazily, only when the app starts

    return run(argv)


if __name__ == "__main__":
    sys.exit(main())
