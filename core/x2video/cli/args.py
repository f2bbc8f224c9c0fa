"""argparse types shared by the `x2video` subcommands and the benches (kept import-light: the heavy
modules load when an argument is parsed, not when a parser is built). Flags of settings dataclasses
are generated from their fields: `x2video.fields`."""
from __future__ import annotations

import argparse


def size_arg(text: str) -> tuple[int, int]:
    """argparse type: 'WxH' -> (width, height) by `x2video.fields.parse_size`."""
    from x2video.fields import parse_size

    try:
        return parse_size(text)
    except ValueError as e:
        raise argparse.ArgumentTypeError(str(e)) from e

