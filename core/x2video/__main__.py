"""``python -m x2video`` runs the command line."""
import sys

from x2video.cli import main

sys.exit(main())
