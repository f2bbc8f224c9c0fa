"""`Edits`: everything a person did to a shot, as plain serialisable data (masks, ops, drops, prompts, reference).

Masks are addressed by name (the key of `edits.masks`), ops by the mask they name. Mutation, in the style an
undo stack needs:
- masks: `add_mask`, `rename_mask`, `remove_mask` (these keep the ops and local prompts that name a mask
  consistent); a mask's frames and object ids through its `Mask` (``edits.masks[name].paint(t, array)``);
- ops: ``edits.ops.append(op)`` / ``edits.ops[i] = op`` / ``del edits.ops[i]``, applied in list order;
  `set_tuning` / `reset_tuning` replace a target's tuning ops, `set_masked_out` its `MaskOut`;
- `set_dropped` (``edits.dropped`` is a set of intrinsic channel names), ``edits.global_prompt``,
  `set_local_prompt` (local prompts are bound to masks), ``edits.reference = Reference(...)`` or None.
Snapshots for undo: ``copy.deepcopy(edits)``; equality compares arrays by value.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from x2video.channels import INTRINSIC
from x2video.edits.masks import Mask
from x2video.edits.ops import MaskOut, Op, op_from_dict
from x2video.edits.tuning import NEUTRAL_TUNING, TUNING_OPS, ops_for, tuning_of, with_value

if TYPE_CHECKING:
    from x2video.shot import Shot

_EDIT_FIELDS = {"masks", "ops", "dropped", "global_prompt", "local_prompts", "reference"}


@dataclass
class Prompts:
    """Global prompt (everywhere) and local prompts (each only inside its mask)."""

    global_prompt: str = ""
    local: list[str] = field(default_factory=list)


@dataclass
class Reference:
    """The reference frame: an image file (`path`, relative to the project folder allowed) that sits
    at frame `at` (default 0: a photo or a look to follow from the start; a rendered frame used as
    the reference sits where it was rendered), or frame `frame` of the shot's `rgb/` channel, which
    sits at that frame."""

    path: str | None = None
    frame: int | None = None
    at: int | None = None

    def __post_init__(self) -> None:
        if (self.path is None) == (self.frame is None):
            raise ValueError("reference: give exactly one of 'path' (an image file) or 'frame' (a shot frame index)")
        if self.frame is not None and (not isinstance(self.frame, int) or self.frame < 0):
            raise ValueError(f"reference.frame: {self.frame!r} is not a frame index")
        if self.at is not None and (self.path is None or not isinstance(self.at, int) or self.at < 0):
            raise ValueError(f"reference.at: {self.at!r} is not a frame index for an image file (a shot frame sits at 'frame')")

    @property
    def position(self) -> int:
        """The shot frame the reference sits at."""
        return self.frame if self.frame is not None else (self.at or 0)

    def describe(self) -> str:
        """One line for a person: which image or shot frame, and where it sits."""
        if self.path is not None:
            return f"Image {Path(self.path).name} (placed at frame {self.position})"
        return f"Shot frame {self.frame} (rgb channel)"

    def to_dict(self) -> dict[str, Any]:
        if self.path is None:
            return {"frame": self.frame}
        return {"path": self.path} if self.at is None else {"path": self.path, "at": self.at}

    @classmethod
    def from_dict(cls, d: Any, where: str = "reference") -> "Reference":
        if not isinstance(d, dict):
            raise ValueError(f"{where}: expected an object")
        unknown = set(d) - {"path", "frame", "at"}
        if unknown:
            raise ValueError(f"{where}: unknown field(s) {', '.join(sorted(unknown))}")
        try:
            return cls(path=d.get("path"), frame=d.get("frame"), at=d.get("at"))
        except ValueError as exc:
            raise ValueError(f"{where}: {exc}") from None


@dataclass
class Edits:
    """What the person did; `apply_edits(shot, edits, t)` turns it into the model's input."""

    masks: dict[str, Mask] = field(default_factory=dict)
    ops: list[Op] = field(default_factory=list)
    dropped: set[str] = field(default_factory=set)
    global_prompt: str = ""
    #: mask name -> local prompt; the order of this dict is the order of local prompts
    local_prompts: dict[str, str] = field(default_factory=dict)
    reference: Reference | None = None

    @classmethod
    def for_shot(cls, shot: "Shot | None") -> "Edits":
        """No edits yet; the global prompt starts as the shot's caption."""
        return cls(global_prompt=shot.info.caption if shot is not None and shot.info.caption else "")

    # -- masks --------------------------------------------------------------------------------
    def add_mask(self, name: str) -> str:
        """Add an empty mask named `name`, or `name (2)`, `name (3)` ... when taken; returns the name given."""
        base, k = name, 2
        while name in self.masks:
            name = f"{base} ({k})"
            k += 1
        self.masks[name] = Mask()
        return name

    def local_prompt_masks(self) -> list[str]:
        """Names of the masks that carry a (non-empty) local prompt, in `prompts().local` order."""
        return [name for name, text in self.local_prompts.items() if text.strip()]

    def prompts(self) -> Prompts:
        """The global prompt and the local prompts, in the order of `local_prompt_masks()`."""
        return Prompts(global_prompt=self.global_prompt, local=[self.local_prompts[n] for n in self.local_prompt_masks()])

    def rename_mask(self, old: str, new: str) -> None:
        """Rename a mask and every op / local prompt that names it (keeps order)."""
        if old not in self.masks:
            raise KeyError(f"no mask {old!r}")
        if new in self.masks and new != old:
            raise ValueError(f"a mask named {new!r} already exists")
        self.masks = {(new if k == old else k): v for k, v in self.masks.items()}
        self.local_prompts = {(new if k == old else k): v for k, v in self.local_prompts.items()}
        for op in self.ops:
            if op.mask == old:
                op.mask = new

    def remove_mask(self, name: str) -> None:
        """Remove a mask with its local prompt and the ops bound to it."""
        self.masks.pop(name)
        self.local_prompts.pop(name, None)
        self.ops = [op for op in self.ops if op.mask != name]

    def local_prompt(self, mask: str) -> str:
        """The local prompt bound to `mask` ("" when none)."""
        return self.local_prompts.get(mask, "")

    def set_local_prompt(self, mask: str, text: str) -> None:
        """Bind `text` to `mask` as its local prompt; blank text removes it."""
        self._mask(mask)
        if text.strip():
            self.local_prompts[mask] = text
        else:
            self.local_prompts.pop(mask, None)

    def masked_out(self, mask: str) -> bool:
        """Whether a `MaskOut` op (the paper's "mask A|M|R") is bound to `mask`."""
        return any(isinstance(op, MaskOut) and op.mask == mask for op in self.ops)

    def set_masked_out(self, mask: str, on: bool) -> None:
        """Bind a `MaskOut` op to `mask` (appended), or remove it."""
        self._mask(mask)
        self.ops = [op for op in self.ops if not (isinstance(op, MaskOut) and op.mask == mask)]
        if on:
            self.ops.append(MaskOut(mask=mask))

    def set_dropped(self, channel: str, on: bool) -> None:
        """Drop an intrinsic channel from the model's input, or keep it."""
        if channel not in INTRINSIC:
            raise ValueError(f"unknown channel {channel!r} (one of {', '.join(INTRINSIC)})")
        (self.dropped.add if on else self.dropped.discard)(channel)

    def _mask(self, name: str | None) -> None:
        if name is not None and name not in self.masks:
            raise KeyError(f"no mask {name!r}")

    # -- parametric tuning (see x2video.edits.tuning) -------------------------------------------
    def tuning(self, mask: str | None) -> dict[str, Any]:
        """The tuning values of `mask` (None: the whole frame), read from its ops (colours sRGB)."""
        self._mask(mask)
        return tuning_of(self.ops, mask)

    def set_tuning(self, mask: str | None, key: str, value: Any) -> None:
        """Set one tuning value of `mask` (None: the whole frame); its ops are rewritten in place."""
        self._replace_tuning(mask, with_value(self.tuning(mask), key, value))

    def reset_tuning(self, mask: str | None) -> None:
        """Remove the tuning ops of `mask` (None: the whole frame)."""
        self._mask(mask)
        self._replace_tuning(mask, dict(NEUTRAL_TUNING))

    def _replace_tuning(self, mask: str | None, values: dict[str, Any]) -> None:
        """The target's tuning ops become `ops_for(values)`, where its first one stood (else at the end)."""
        mine = {k for k, op in enumerate(self.ops) if op.mask == mask and isinstance(op, TUNING_OPS)}
        rest = [op for k, op in enumerate(self.ops) if k not in mine]
        at = min(min(mine, default=len(self.ops)), len(rest))
        self.ops = rest[:at] + ops_for(values, mask) + rest[at:]

    def validate(self) -> None:
        """Raise ValueError when something names a missing mask or channel."""
        bad = sorted(set(self.dropped) - set(INTRINSIC))
        if bad:
            raise ValueError(f"edits.dropped: unknown channel(s) {', '.join(bad)} (one of {', '.join(INTRINSIC)})")
        for i, op in enumerate(self.ops):
            if op.mask is not None and op.mask not in self.masks:
                raise ValueError(f"edits.ops[{i}] ({op.kind}): mask {op.mask!r} does not exist")
            op.validate(f"edits.ops[{i}]")
        for name in self.local_prompts:
            if name not in self.masks:
                raise ValueError(f"edits.local_prompts: mask {name!r} does not exist")

    # -- serialisation -----------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        """JSON-able description; mask arrays are not included (see `mask_arrays`)."""
        return {
            "masks": {name: m.to_dict() for name, m in self.masks.items()},
            "ops": [op.to_dict() for op in self.ops],
            "dropped": sorted(self.dropped),
            "global_prompt": self.global_prompt,
            "local_prompts": dict(self.local_prompts),
            "reference": None if self.reference is None else self.reference.to_dict(),
        }

    def mask_arrays(self) -> dict[str, dict[int, np.ndarray]]:
        """mask name -> frame -> painted (H, W) float32 array (what `to_dict` leaves out)."""
        return {name: dict(m.frames) for name, m in self.masks.items()}

    @classmethod
    def from_dict(cls, d: Any, arrays: dict[str, dict[int, np.ndarray]] | None = None, where: str = "edits") -> "Edits":
        """Inverse of `to_dict` (+ `mask_arrays`); unknown fields are errors naming their path."""
        if not isinstance(d, dict):
            raise ValueError(f"{where}: expected an object")
        unknown = set(d) - _EDIT_FIELDS
        if unknown:
            raise ValueError(f"{where}: unknown field(s) {', '.join(sorted(unknown))}")
        arrays = arrays or {}
        masks_doc = d.get("masks", {})
        if not isinstance(masks_doc, dict):
            raise ValueError(f"{where}.masks: expected an object of name -> mask")
        masks = {name: Mask.from_dict(md, arrays.get(name), f"{where}.masks[{name!r}]") for name, md in masks_doc.items()}
        ops_doc = d.get("ops", [])
        if not isinstance(ops_doc, list):
            raise ValueError(f"{where}.ops: expected a list")
        ops = [op_from_dict(od, f"{where}.ops[{i}]") for i, od in enumerate(ops_doc)]
        dropped = d.get("dropped", [])
        if not isinstance(dropped, list):
            raise ValueError(f"{where}.dropped: expected a list of channel names")
        lp = d.get("local_prompts", {})
        if not isinstance(lp, dict) or not all(isinstance(v, str) for v in lp.values()):
            raise ValueError(f"{where}.local_prompts: expected an object of mask name -> prompt text")
        gp = d.get("global_prompt", "")
        if not isinstance(gp, str):
            raise ValueError(f"{where}.global_prompt: expected text")
        ref = d.get("reference")
        edits = cls(
            masks=masks,
            ops=ops,
            dropped=set(dropped),
            global_prompt=gp,
            local_prompts=dict(lp),
            reference=None if ref is None else Reference.from_dict(ref, f"{where}.reference"),
        )
        try:
            edits.validate()
        except ValueError as exc:
            raise ValueError(str(exc).replace("edits.", f"{where}.", 1)) from None
        return edits
