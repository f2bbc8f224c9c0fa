"""`x2video` command line: each module in this package that defines `register(subparsers)` adds a subcommand."""
from __future__ import annotations

import argparse
import importlib
import logging
import pkgutil
import sys


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="x2video", description="X2Video Studio: intrinsic channels to video")
    parser.add_argument("-v", "--verbose", action="store_true", help="log debug messages")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for mod in sorted(pkgutil.iter_modules(__path__), key=lambda m: m.name):
        if mod.name.startswith("_"):
            continue
        module = importlib.import_module(f"{__name__}.{mod.name}")
        register = getattr(module, "register", None)
        if register is not None:
            register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    try:
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    except (ValueError, FileNotFoundError, KeyError) as exc:
        # Bad input: say what and where, no traceback (use -v for one).
        if args.verbose:
            raise
        print(f"x2video {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        # The machine, not the input: a full disk (x2video.io.atomic.DiskFullError names the folder and the space
        # needed), a folder we may not write, a file that vanished while we read it. Exit 1, no traceback.
        if args.verbose:
            raise
        text = f"{exc.filename}: {exc.strerror}" if exc.filename is not None else (exc.strerror if type(exc) is OSError and exc.strerror else str(exc))
        print(f"x2video {args.command}: error: {text}", file=sys.stderr)
        return 1
