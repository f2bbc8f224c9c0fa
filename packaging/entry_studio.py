"""Bundle entry point of the editor (`x2video-studio [SHOT|PROJECT]`, `x2video-studio --selftest`)."""
import sys

from x2video_app.__main__ import main

if __name__ == "__main__":
    sys.exit(main())
