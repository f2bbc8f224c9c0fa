"""The editor's Qt-free state model: the open shot, its Edits, the current frame and view, and the render.

Views subscribe to the `Signal`s here and never own state; every change of the Edits goes
through a method of this class (undo commands call them too), which bumps `version` so the
edited-channel cache and the window title stay right.
"""
from __future__ import annotations

import copy
import logging
from pathlib import Path

import cv2
import numpy as np

from x2video.channels import INTRINSIC
from x2video.conditioning.edited import apply_edits, resolve_reference
from x2video.conditioning.frame import FrameConditioning
from x2video.edits import Edits
from x2video.shot import Shot
from x2video_app.state.display import MASK_COLOURS, VIEW_MODES, channel_to_u8, checker, overlay_masks, side_by_side
from x2video_app.state.render_state import RenderState
from x2video_app.state.signals import Signal

log = logging.getLogger(__name__)


class Document:
    """One open shot and what the person did to it."""

    def __init__(self) -> None:
        self.shot: Shot | None = None
        self.shot_path: str | None = None
        self.project_path: Path | None = None
        self.edits: Edits | None = None
        self.frame = 0
        self.view = "albedo"
        self.selected_mask = -1
        self.edit_global = True
        self.version = 0
        self.render = RenderState()
        #: per-mask display state that is not part of the Edits, keyed by mask name
        self.hidden: set[str] = set()
        self.colours: dict[str, tuple[int, int, int]] = {}
        self._cond_cache: dict[int, tuple[int, FrameConditioning]] = {}
        #: the live preview's frame on screen (`x2video_app.state.live_request.LiveResult`: `.t`, `.image`), newer than the
        #: render's frame of it; None when there is none (no edit since the render)
        self.live = None
        self._stroke: tuple[int, int, np.ndarray, np.ndarray] | None = None  # (mask, t, before, working)
        self._last_pt: tuple[float, float] | None = None
        # signals
        self.shot_changed = Signal("shot_changed")
        self.frame_changed = Signal("frame_changed")
        self.view_changed = Signal("view_changed")
        self.edits_changed = Signal("edits_changed")  # (kind: str)
        self.selection_changed = Signal("selection_changed")

    # -- shot / project --------------------------------------------------------
    def set_shot(self, shot: Shot, path: str | None, edits: Edits | None = None, project_path: Path | None = None) -> None:
        self.shot, self.shot_path = shot, path
        self.edits = edits if edits is not None else Edits.for_shot(shot)
        self.project_path = project_path
        self.frame = 0
        self.selected_mask = 0 if self.num_masks else -1
        self.edit_global = self.selected_mask < 0
        self.hidden.clear()
        self.colours.clear()
        self.render.clear_frames()
        self.render.status = "idle"
        self._bump()
        self.shot_changed.emit()
        self.edits_changed.emit("all")
        self.selection_changed.emit()
        self.frame_changed.emit(self.frame)

    @property
    def num_frames(self) -> int:
        return 0 if self.shot is None else self.shot.num_frames

    @property
    def base_caption(self) -> str:
        """What a render keeps as its base (`x2video.base.plan.base_caption`): the shot's path-traced frames, or ''."""
        if self.shot is None:
            return ""
        from x2video.base.plan import base_caption
        from x2video.render.settings import RenderSettings

        return base_caption(self.shot, RenderSettings())

    @property
    def num_masks(self) -> int:
        return 0 if self.edits is None else len(self.edits.masks)

    def mask_name(self, i: int) -> str:
        """The name (what the Edits address a mask by) of the mask in row `i` of the mask list."""
        return list(self.edits.masks)[i]

    @property
    def size(self) -> tuple[int, int]:
        return (224, 320) if self.shot is None else self.shot.size

    def set_frame(self, t: int) -> None:
        t = max(0, min(self.num_frames - 1, int(t)))
        if t != self.frame:
            self.frame = t
            self.frame_changed.emit(t)

    def set_view(self, view: str) -> None:
        if view not in VIEW_MODES:
            raise ValueError(f"unknown view {view!r}; one of {VIEW_MODES}")
        if view != self.view:
            self.view = view
            self.view_changed.emit(view)

    # -- edits (every mutation funnels through here) ---------------------------
    def _bump(self) -> None:
        self.version += 1
        self._cond_cache.clear()

    def changed(self, kind: str) -> None:
        """Call after mutating `self.edits` (undo commands do)."""
        self._bump()
        self.edits_changed.emit(kind)

    def snapshot(self) -> Edits:
        """A deep copy of the Edits (undo of structural changes: add/remove mask)."""
        return copy.deepcopy(self.edits)

    def restore(self, edits: Edits, selected: int | None = None) -> None:
        self.edits = copy.deepcopy(edits)
        if self._stroke is not None:  # an undo in the middle of a stroke ends the stroke
            self._stroke = None
        if selected is not None:
            self.selected_mask = selected
        self.selected_mask = min(self.selected_mask, self.num_masks - 1)
        self.changed("all")
        self.selection_changed.emit()

    def select_mask(self, i: int) -> None:
        i = i if 0 <= i < self.num_masks else -1
        if i != self.selected_mask:
            self.selected_mask = i
            if i < 0:
                self.edit_global = True
            self.selection_changed.emit()

    def set_edit_global(self, on: bool) -> None:
        self.edit_global = bool(on) or self.selected_mask < 0
        self.selection_changed.emit()

    def edit_target(self) -> int | None:
        """None = the whole frame, else the mask index parametric edits apply to."""
        return None if self.edit_global or self.selected_mask < 0 else self.selected_mask

    def mask_colour(self, i: int) -> tuple[int, int, int]:
        return self.colours.get(self.mask_name(i)) or MASK_COLOURS[i % len(MASK_COLOURS)]

    def set_mask_colour(self, i: int, colour: tuple[int, int, int]) -> None:
        self.colours[self.mask_name(i)] = tuple(colour)  # type: ignore[assignment]

    def set_mask_visible(self, i: int, on: bool) -> None:
        name = self.mask_name(i)
        (self.hidden.discard if on else self.hidden.add)(name)
        self.edits_changed.emit("display")

    @property
    def base_dir(self) -> Path | None:
        return None if self.project_path is None else self.project_path.parent

    def masks_summary(self) -> list[dict]:
        return [
            {
                "name": name,
                "colour": self.mask_colour(i),
                "visible": name not in self.hidden,
                "prompt": self.edits.local_prompt(name),
                "mask_out": self.edits.masked_out(name),
            }
            for i, name in enumerate(self.edits.masks)
        ]

    def reference_image(self) -> np.ndarray | None:
        """Linear RGB (H, W, 3) of the reference at the shot's size, or None (no shot, none set, or unreadable)."""
        if self.shot is None or self.edits is None or self.edits.reference is None:
            return None
        try:
            r = resolve_reference(self.shot, self.edits, self.base_dir)
        except (OSError, ValueError):
            return None
        return None if r is None else r[1]

    # -- painting --------------------------------------------------------------
    @property
    def stroking(self) -> bool:
        """Whether a brush/eraser stroke is under way (its undo step is pushed when it ends)."""
        return self._stroke is not None

    def begin_stroke(self, x: float, y: float, radius: float, erase: bool) -> bool:
        """Start a brush/eraser stroke on the selected mask at frame `self.frame`; False when no mask is selected."""
        if self.selected_mask < 0 or self.shot is None:
            return False
        m = self.edits.masks[self.mask_name(self.selected_mask)].painted(self.frame, self.size)
        self._stroke = (self.selected_mask, self.frame, m.copy(), m.copy())
        self._last_pt = None
        self.stroke_to(x, y, radius, erase)
        return True

    def stroke_to(self, x: float, y: float, radius: float, erase: bool) -> None:
        if self._stroke is None:
            return
        i, t, _, work = self._stroke
        val = 0.0 if erase else 1.0
        r = max(1, int(round(radius)))
        p = (int(round(x)), int(round(y)))
        if self._last_pt is None:
            cv2.circle(work, p, r, val, -1, lineType=cv2.LINE_8)
        else:
            cv2.line(work, self._last_pt, p, val, 2 * r, lineType=cv2.LINE_8)
            cv2.circle(work, p, r, val, -1, lineType=cv2.LINE_8)
        self._last_pt = p
        self.edits.masks[self.mask_name(i)].set_painted(t, work)
        self.changed("mask")

    def end_stroke(self) -> tuple[int, int, np.ndarray, np.ndarray] | None:
        """Finish the stroke: (mask, frame, before, after) for the undo command, or None if nothing changed."""
        s, self._stroke, self._last_pt = self._stroke, None, None
        if s is None:
            return None
        i, t, before, after = s
        return None if np.array_equal(before, after) else (i, t, before, after.copy())

    def object_at(self, x: float, y: float) -> int | None:
        """The object id under image point (x, y) on the current frame (None: no ids channel, outside, background)."""
        if self.shot is None or not self.shot.has("ids"):
            return None
        h, w = self.size
        xi, yi = int(x), int(y)
        if not (0 <= xi < w and 0 <= yi < h):
            return None
        oid = int(self.shot.channel("ids", self.frame)[yi, xi, 0])
        return oid if oid > 0 else None

    def set_mask_frame(self, i: int, t: int, m: np.ndarray) -> None:
        self.edits.masks[self.mask_name(i)].set_painted(t, m)
        self.changed("mask")

    # -- edited channels and what the viewer shows -----------------------------
    def conditioning(self, t: int) -> FrameConditioning:
        hit = self._cond_cache.get(t)
        if hit is not None and hit[0] == self.version:
            return hit[1]
        cond = apply_edits(self.shot, self.edits, t)
        if len(self._cond_cache) > 8:
            self._cond_cache.clear()
        self._cond_cache[t] = (self.version, cond)
        return cond

    def mask_layers(self, t: int) -> list[tuple[np.ndarray, tuple[int, int, int]]]:
        out = []
        for i, (name, mask) in enumerate(self.edits.masks.items()):
            if name not in self.hidden:
                out.append((mask.at(self.shot, t), self.mask_colour(i)))
        return out

    def rendered_u8(self, t: int) -> np.ndarray:
        live = self.live
        img = live.image if live is not None and live.t == t else self.render.image(t)  # else the render's frame, or its formula preview
        return checker(self.size) if img is None else channel_to_u8("rgb", img.astype(np.float32), self.size)

    def display_image(self) -> np.ndarray:
        """uint8 (H, W, 3) for the current view and frame."""
        if self.shot is None:
            return checker(self.size)
        t, v = self.frame, self.view
        if v in INTRINSIC:
            base = channel_to_u8(v, self.conditioning(t).channels.get(v), self.size)
        elif v == "ids":
            base = channel_to_u8("ids", self.shot.channel("ids", t) if self.shot.has("ids") else None, self.size)
        elif v == "masks":
            cond = self.conditioning(t)
            base = channel_to_u8("albedo", cond.channels.get("albedo"), self.size)
            return overlay_masks(base, self.mask_layers(t))
        elif v == "reference":
            ref = self.reference_image()
            base = checker(self.size) if ref is None else channel_to_u8("rgb", ref, self.size)
        elif v == "rendered":
            base = self.rendered_u8(t)
        else:  # side-by-side: edited albedo | rendered output
            cond = self.conditioning(t)
            base = side_by_side(channel_to_u8("albedo", cond.channels.get("albedo"), self.size), self.rendered_u8(t))
        return base
