"""Parametric edit operations (the paper's parametric tuning): plain dataclasses, each with a pure `apply`.

Every op acts on one frame's channels inside a mask (or everywhere when `mask` is None):
``out = edited * m + base * (1 - m)`` where m > 0, and ``base`` bit for bit where m == 0.
Albedo colours are linear RGB in [0, 1]; HSV shifts act on the sRGB-encoded albedo (what a
person sees), then decode back.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, field, fields
from typing import Any, ClassVar

import cv2
import numpy as np

from x2video.channels import LIGHT_PASSES, linear_to_srgb, srgb_to_linear


def blend(base: np.ndarray, edited: np.ndarray, m: np.ndarray | None) -> np.ndarray:
    """`edited` where m == 1, `base` unchanged where m == 0, linear in between. m: (H, W) or None."""
    if m is None:
        return edited.astype(np.float32)
    w = m[..., None]
    return np.where(w > 0, edited * w + base * (1.0 - w), base).astype(np.float32)


def _rgb(v: Any, where: str) -> tuple[float, float, float]:
    try:
        c = tuple(float(x) for x in v)
    except TypeError:
        raise ValueError(f"{where}: expected three numbers, got {v!r}") from None
    if len(c) != 3 or not all(np.isfinite(c)):
        raise ValueError(f"{where}: expected three finite numbers, got {v!r}")
    return c  # type: ignore[return-value]


@dataclass
class Op:
    """Base: `mask` names a mask of the Edits (None = everywhere)."""

    kind: ClassVar[str] = ""
    #: the channel this op reads and writes
    channel: ClassVar[str] = ""
    #: the passes (`x2video.channels.PASSES`) it edits as it edits its channel: the light operations' light
    #: passes, so that a light edit scales every term of a path-traced frame, not only its diffuse light
    passes: ClassVar[tuple[str, ...]] = ()
    mask: str | None = None

    def edit(self, x: np.ndarray) -> np.ndarray:  # pragma: no cover - abstract
        raise AssertionError("subclasses implement edit")

    def apply(self, channels: dict[str, np.ndarray | None], m: np.ndarray | None) -> None:
        """Edit `channels[self.channel]` (replaced, not modified in place) within mask m."""
        x = channels.get(self.target())
        if x is None:
            return
        channels[self.target()] = blend(x, self.edit(x), m)

    def apply_passes(self, passes: dict[str, np.ndarray], m: np.ndarray | None) -> None:
        """Edit each of `self.passes` present in `passes` (replaced, not modified in place) within mask m."""
        for name in self.passes:
            x = passes.get(name)
            if x is not None:
                passes[name] = blend(x, self.edit(x), m)

    def target(self) -> str:
        return self.channel

    def validate(self, where: str) -> None:
        """Raise ValueError naming `where` for out-of-range parameters."""

    def to_dict(self) -> dict[str, Any]:
        return {"op": self.kind, **asdict(self)}


@dataclass
class AlbedoSet(Op):
    """Albedo := colour (linear RGB)."""

    kind: ClassVar[str] = "albedo_set"
    channel: ClassVar[str] = "albedo"
    color: tuple[float, float, float] = (0.5, 0.5, 0.5)

    def validate(self, where: str) -> None:
        self.color = _rgb(self.color, f"{where}.color")

    def edit(self, x: np.ndarray) -> np.ndarray:
        return np.broadcast_to(np.clip(np.asarray(self.color, np.float32), 0, 1), x.shape)


@dataclass
class AlbedoTint(Op):
    """Albedo *= colour (per-channel multiply), clipped to [0, 1]."""

    kind: ClassVar[str] = "albedo_tint"
    channel: ClassVar[str] = "albedo"
    color: tuple[float, float, float] = (1.0, 1.0, 1.0)

    def validate(self, where: str) -> None:
        self.color = _rgb(self.color, f"{where}.color")

    def edit(self, x: np.ndarray) -> np.ndarray:
        return np.clip(x * np.asarray(self.color, np.float32), 0, 1)


@dataclass
class AlbedoHSV(Op):
    """Hue += `hue` degrees, saturation *= `saturation`, value *= `value` (on sRGB-encoded albedo)."""

    kind: ClassVar[str] = "albedo_hsv"
    channel: ClassVar[str] = "albedo"
    hue: float = 0.0
    saturation: float = 1.0
    value: float = 1.0

    def validate(self, where: str) -> None:
        if self.saturation < 0 or self.value < 0:
            raise ValueError(f"{where}: saturation and value factors must be >= 0")

    def edit(self, x: np.ndarray) -> np.ndarray:
        hsv = cv2.cvtColor(np.ascontiguousarray(linear_to_srgb(x)), cv2.COLOR_RGB2HSV)  # H in [0, 360)
        hsv[..., 0] = np.mod(hsv[..., 0] + np.float32(self.hue), 360.0)
        hsv[..., 1] = np.clip(hsv[..., 1] * np.float32(self.saturation), 0, 1)
        hsv[..., 2] = np.clip(hsv[..., 2] * np.float32(self.value), 0, 1)
        return srgb_to_linear(cv2.cvtColor(hsv, cv2.COLOR_HSV2RGB))


@dataclass
class ScalarOp(Op):
    """Roughness or metallic: "set" (:= value), "offset" (+= value) or "scale" (*= value), clipped to [0, 1]."""

    kind: ClassVar[str] = "scalar"
    target_channel: str = "roughness"
    mode: str = "set"
    value: float = 0.5

    def target(self) -> str:
        return self.target_channel

    def validate(self, where: str) -> None:
        if self.target_channel not in ("roughness", "metallic"):
            raise ValueError(f"{where}.target_channel: {self.target_channel!r} is not 'roughness' or 'metallic'")
        if self.mode not in ("set", "offset", "scale"):
            raise ValueError(f"{where}.mode: {self.mode!r} is not 'set', 'offset' or 'scale'")
        if not np.isfinite(self.value):
            raise ValueError(f"{where}.value: must be finite")

    def edit(self, x: np.ndarray) -> np.ndarray:
        v = np.float32(self.value)
        y = np.full_like(x, v) if self.mode == "set" else (x + v if self.mode == "offset" else x * v)
        return np.clip(y, 0, 1)


@dataclass
class Exposure(Op):
    """Irradiance (and the light passes: glossy, emission) *= 2 ** stops."""

    kind: ClassVar[str] = "exposure"
    channel: ClassVar[str] = "irradiance"
    passes: ClassVar[tuple[str, ...]] = LIGHT_PASSES
    stops: float = 0.0

    def validate(self, where: str) -> None:
        if not np.isfinite(self.stops) or abs(self.stops) > 20:
            raise ValueError(f"{where}.stops: {self.stops!r} outside [-20, 20]")

    def edit(self, x: np.ndarray) -> np.ndarray:
        return x * np.float32(2.0**self.stops)


@dataclass
class LightTint(Op):
    """Irradiance (and the light passes: glossy, emission) *= colour (per-channel multiply, >= 0)."""

    kind: ClassVar[str] = "light_tint"
    channel: ClassVar[str] = "irradiance"
    passes: ClassVar[tuple[str, ...]] = LIGHT_PASSES
    color: tuple[float, float, float] = (1.0, 1.0, 1.0)

    def validate(self, where: str) -> None:
        self.color = _rgb(self.color, f"{where}.color")
        if min(self.color) < 0:
            raise ValueError(f"{where}.color: must be >= 0")

    def edit(self, x: np.ndarray) -> np.ndarray:
        return x * np.asarray(self.color, np.float32)


@dataclass
class MaskOut(Op):
    """The paper's "Mask A|M|R": zero the listed channels inside the (binarised, > 0.5) mask and
    mark the region in the union-mask input; the model fills them in."""

    kind: ClassVar[str] = "mask_out"
    channels: list[str] = field(default_factory=lambda: ["albedo", "metallic", "roughness"])

    def validate(self, where: str) -> None:
        bad = [c for c in self.channels if c not in ("albedo", "metallic", "roughness")]
        if bad or not self.channels:
            raise ValueError(f"{where}.channels: {self.channels!r}; use a non-empty subset of albedo, metallic, roughness")
        if self.mask is None:
            raise ValueError(f"{where}: mask_out needs a mask")

    def apply(self, channels: dict[str, np.ndarray | None], m: np.ndarray | None) -> None:
        region = (m > 0.5)[..., None] if m is not None else True
        for c in self.channels:
            x = channels.get(c)
            if x is not None:
                channels[c] = np.where(region, np.float32(0), x).astype(np.float32)


OPS: dict[str, type[Op]] = {c.kind: c for c in (AlbedoSet, AlbedoTint, AlbedoHSV, ScalarOp, Exposure, LightTint, MaskOut)}


def op_from_dict(d: dict[str, Any], where: str = "op") -> Op:
    """Rebuild an op from `Op.to_dict()` output; unknown kinds or fields are errors naming `where`."""
    if not isinstance(d, dict) or "op" not in d:
        raise ValueError(f"{where}: expected an object with an 'op' field")
    cls = OPS.get(d["op"])
    if cls is None:
        raise ValueError(f"{where}.op: unknown edit operation {d['op']!r} (one of {', '.join(OPS)})")
    names = {f.name for f in fields(cls)}
    unknown = set(d) - names - {"op"}
    if unknown:
        raise ValueError(f"{where}: unknown field(s) {', '.join(sorted(unknown))} for {d['op']!r}")
    kwargs = {k: v for k, v in d.items() if k != "op"}
    for k in ("color",):
        if k in kwargs and isinstance(kwargs[k], list):
            kwargs[k] = tuple(kwargs[k])
    try:
        op = cls(**kwargs)
        op.validate(where)
    except TypeError as exc:
        raise ValueError(f"{where}: bad parameter ({exc})") from None
    if op.mask is not None and not isinstance(op.mask, str):
        raise ValueError(f"{where}.mask: expected a mask name or null, got {op.mask!r}")
    return op
