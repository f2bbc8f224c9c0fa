"""Flags generated from a settings dataclass: each field is declared once, with its type, default and
docstring, and `--field-name` follows from it (nerfstudio/tyro's habit, in plain argparse). Below the
command line (`x2video.cli` calls it; so do the farm's job templates and the benches), so the library
may use it without importing the CLI.

    add_fields(parser, RenderSettings)             # --sampler {ddim,lcm}, --steps N, --seams/--no-seams, ...
    settings = from_args(RenderSettings, args)
    to_flags(RenderSettings, settings)             # back to ['--seed', '3', '--no-seams', ...] (a job template)
"""
from __future__ import annotations

import argparse
import ast
import dataclasses
import functools
import inspect
import textwrap
import types
import typing
from pathlib import Path
from typing import Any, Callable, Iterable, Literal, Mapping


@functools.cache
def field_docs(cls: type) -> dict[str, str]:
    """Field name -> its attribute docstring (the string literal under the annotated assignment),
    whitespace folded. Inherited fields are included."""
    docs: dict[str, str] = {}
    for klass in reversed(cls.__mro__):
        if not dataclasses.is_dataclass(klass):
            continue
        try:
            source = inspect.getsource(klass)
        except (OSError, TypeError):  # no source (a frozen bundle): flags without help, not no flags
            continue
        body = ast.parse(textwrap.dedent(source)).body[0].body
        for node, nxt in zip(body, body[1:]):
            if (isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name) and isinstance(nxt, ast.Expr)
                    and isinstance(nxt.value, ast.Constant) and isinstance(nxt.value.value, str)):
                docs[node.target.id] = " ".join(nxt.value.value.split())
    return docs


def flag(name: str) -> str:
    return "--" + name.replace("_", "-")


def frame_range(text: str) -> tuple[int, int]:
    """argparse type: 'START:STOP' -> (start, stop)."""
    try:
        a, b = (int(v) for v in text.split(":"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"wants START:STOP, got {text!r}") from None
    return a, b


def int_list(text: str) -> tuple[int, ...]:
    """argparse type: '16,32,64' -> (16, 32, 64)."""
    try:
        return tuple(int(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"wants comma-separated integers, got {text!r}") from None


def stops_or_auto(text: str) -> float | str:
    """argparse type: an exposure in stops, or 'auto' (`x2video.io.units.parse_exposure`)."""
    from x2video.io.units import parse_exposure

    try:
        return parse_exposure(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


#: how a value of a (non-optional) field type is read from the command line, and its metavar
PARSERS: dict[Any, tuple[Callable[[str], Any], str | None]] = {
    int: (int, None), float: (float, None), str: (str, None), Path: (Path, "DIR"), tuple[int, int]: (frame_range, "START:STOP"),
    float | str: (stops_or_auto, "STOPS|auto"), tuple[int, ...]: (int_list, "N,N,..."),
}


def _unwrap_optional(tp: Any) -> Any:
    if typing.get_origin(tp) in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        if len(args) == 1:
            return args[0]
    return tp


def _is_optional(cls: type, name: str) -> bool:
    tp = typing.get_type_hints(cls)[name]
    return typing.get_origin(tp) in (typing.Union, types.UnionType) and type(None) in typing.get_args(tp)


def on_off(text: str) -> bool:
    """argparse type of a `bool | None` field: 'on' -> True, 'off' -> False (no flag: None)."""
    if text not in ("on", "off"):
        raise argparse.ArgumentTypeError(f"wants on or off, got {text!r}")
    return text == "on"


def _on_off(value: bool) -> str:
    return "on" if value else "off"


def _default_text(value: Any) -> str:
    if value is None:
        return "unset"
    if isinstance(value, tuple) and len(value) == 2 and all(isinstance(v, int) for v in value):
        return ":".join(map(str, value))
    if isinstance(value, tuple) and all(isinstance(v, int) for v in value):
        return ",".join(map(str, value))
    return f"{value:g}" if isinstance(value, float) else str(value)


def field_kwargs(cls: type, name: str, default: Any = dataclasses.MISSING) -> dict[str, Any]:
    """`add_argument` keywords for the field `name` of the dataclass `cls`: type (choices for a Literal,
    `--x/--no-x` for a bool), default (the field's, unless given) and help (its docstring and default)."""
    tp = _unwrap_optional(typing.get_type_hints(cls)[name])
    if default is dataclasses.MISSING:
        default = getattr(cls(), name)
    doc = field_docs(cls).get(name, "").rstrip(".").replace("%", "%%")  # argparse %-formats help
    kwargs: dict[str, Any] = {"dest": name, "default": default}
    if tp is bool and _is_optional(cls, name):  # three states: --x on, --x off, or left unset (None)
        kwargs.update(type=on_off, metavar="{on,off}", help=f"{doc} (default: {'unset' if default is None else _on_off(default)})")
        return kwargs
    if tp is bool:
        kwargs["action"] = argparse.BooleanOptionalAction
        kwargs["help"] = f"{doc} (default: {'on' if default else 'off'})"
        return kwargs
    if typing.get_origin(tp) is Literal:
        kwargs["choices"] = typing.get_args(tp)
        kwargs["type"] = type(typing.get_args(tp)[0])
    else:
        kwargs["type"], metavar = PARSERS[tp]
        if metavar:
            kwargs["metavar"] = metavar
    kwargs["help"] = f"{doc} (default: {_default_text(default)})"
    return kwargs


def add_fields(parser: argparse.ArgumentParser | argparse._ArgumentGroup, cls: type, *, only: Iterable[str] | None = None,
               skip: Iterable[str] = (), defaults: Any = None, aliases: Mapping[str, str | Iterable[str]] | None = None,
               overrides: Mapping[str, Mapping[str, Any]] | None = None) -> list[str]:
    """Add one flag `--field-name` per field of the dataclass `cls` (all, or `only` those, less `skip`; see
    `field_kwargs`) and return their names. `defaults` (an instance) overrides the class's defaults; `aliases`
    (field -> option strings) adds other names for a field's flag (`--ema` for `ema_decay`; the dest stays the
    field's, so `from_args` reads it); `overrides` (field -> `add_argument` keywords) replaces any of the
    generated ones (`type=size_arg` for a WxH size)."""
    instance = defaults if defaults is not None else cls()
    aliases, overrides = aliases or {}, overrides or {}
    names = [f.name for f in dataclasses.fields(cls)] if only is None else list(only)
    names = [n for n in names if n not in set(skip)]
    unknown = (set(aliases) | set(overrides)) - set(names)
    if unknown:
        raise ValueError(f"{cls.__name__}: aliases/overrides for fields without a flag: {sorted(unknown)}")
    for name in names:
        other = aliases.get(name, ())
        options = [flag(name), *([other] if isinstance(other, str) else other)]
        parser.add_argument(*options, **{**field_kwargs(cls, name, getattr(instance, name)), **overrides.get(name, {})})
    return names


def add_field(parser: argparse.ArgumentParser | argparse._ArgumentGroup, option: str, cls: type, name: str, **overrides: Any) -> None:
    """One flag whose name is not its field's (`--channel-drop` for `AugmentConfig.channel_drop_p`): type, default
    and help from the field; `overrides` replace any of them (dest stays the flag's own)."""
    kwargs = field_kwargs(cls, name, overrides.pop("default", dataclasses.MISSING))
    kwargs.pop("dest")
    parser.add_argument(option, **{**kwargs, **overrides})


def from_args(cls: type, args: argparse.Namespace, **overrides: Any) -> Any:
    """An instance of `cls` from the parsed flags `add_fields` added (fields without a flag keep their defaults)."""
    values = {f.name: getattr(args, f.name) for f in dataclasses.fields(cls) if f.init and hasattr(args, f.name)}
    return cls(**{**values, **overrides})


def flag_value(value: Any) -> str:
    """The command-line text of a field's value (the inverse of its `PARSERS` entry)."""
    if isinstance(value, tuple) and len(value) == 2 and all(isinstance(v, int) for v in value):
        return ":".join(map(str, value))
    if isinstance(value, tuple) and all(isinstance(v, int) for v in value):
        return ",".join(map(str, value))
    return repr(value) if isinstance(value, float) else str(value)


def to_flags(cls: type, instance: Any, *, only_changed: bool = True) -> list[str]:
    """The flags `add_fields(parser, cls)` would parse back into `instance`: `--field-name VALUE` (`--x`/`--no-x` for a
    bool) for each field that differs from the class's default (all fields with `only_changed=False`). A field left
    unset (None) gives no flag; one set to None over a non-None default has no flag to say so (ValueError)."""
    default = cls()
    out: list[str] = []
    for f in dataclasses.fields(cls):
        if not f.init:
            continue
        value, base = getattr(instance, f.name), getattr(default, f.name)
        if only_changed and value == base:
            continue
        if value is None:
            if base is None:
                continue
            raise ValueError(f"{cls.__name__}.{f.name} is None, which no flag {flag(f.name)} can say")
        if isinstance(value, bool) and _is_optional(cls, f.name):
            out += [flag(f.name), _on_off(value)]
        elif isinstance(value, bool):
            out.append(flag(f.name) if value else "--no-" + f.name.replace("_", "-"))
        else:
            out += [flag(f.name), flag_value(value)]
    return out


def parse_size(text: str, minimum: int = 1) -> tuple[int, int]:
    """'320x224' -> (width, height) = (320, 224), at least `minimum` pixels each way (the one "WxH" parser: the CLI,
    the data sets, the farm and the benches read sizes through it)."""
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError as e:
        raise ValueError(f"size {text!r} is not WIDTHxHEIGHT (e.g. 160x112)") from e
    if w <= 0 or h <= 0:
        raise ValueError(f"size {text!r} must be positive")
    if w < minimum or h < minimum:
        raise ValueError(f"size {text!r}: width and height must be at least {minimum}")
    return w, h
