"""Bundle entry point of the command line (`x2video render ...`)."""
import multiprocessing
import sys

if __name__ == "__main__":
    multiprocessing.freeze_support()  # `x2video dataset make --workers N` spawns worker processes
    from x2video.cli import main

    sys.exit(main())
