"""Flags generated from settings dataclasses: moved below the command line to `x2video.fields` (the farm and
the benches use them too); these names stay importable from here."""
from x2video.fields import (
    PARSERS,
    add_field,
    add_fields,
    field_docs,
    field_kwargs,
    flag,
    flag_value,
    frame_range,
    from_args,
    int_list,
    parse_size,
    stops_or_auto,
    to_flags,
)

__all__ = [
    "PARSERS", "add_field", "add_fields", "field_docs", "field_kwargs", "flag", "flag_value",
    "frame_range", "from_args", "int_list", "parse_size", "stops_or_auto", "to_flags",
]
