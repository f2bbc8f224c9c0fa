"""What the live preview asks for and gets back (issue 43), without Qt: a request for one frame under a snapshot of the
edits, and the worker's result. `x2video_app._qt.live_previewer` renders them; the Document holds the one on screen."""
from __future__ import annotations

import copy
import dataclasses
from dataclasses import dataclass
from typing import Any

import numpy as np

from x2video.edits import Edits, Mask
from x2video.render.settings import RenderSettings


def snapshot_edits(edits: Edits) -> Edits:
    """A copy of `edits` a worker may read while the person keeps editing: new containers, the masks' painted arrays
    shared (a `Mask` never modifies an array in place: painting stores a new one), so a stroke copies no pixels."""
    masks = {name: Mask(frames=dict(m.frames), ids=list(m.ids), hold=m.hold) for name, m in edits.masks.items()}
    return dataclasses.replace(edits, masks=masks, ops=copy.deepcopy(edits.ops), dropped=set(edits.dropped),
                               local_prompts=dict(edits.local_prompts), reference=copy.copy(edits.reference))


@dataclass(frozen=True)
class LiveRequest:
    """Frame `t` of `shot` under `edits` (the Document's `version` of them), as a preview or at full quality (`final`).
    `choice`: the tiers (`x2video.render.live.LiveChoice`), decided on the GUI thread once the model is built;
    None before (the worker decides, with no model: the formula)."""

    id: int
    t: int
    version: int
    final: bool
    shot: Any
    edits: Edits
    settings: RenderSettings
    model: Any
    choice: Any
    asked_at: float


@dataclass
class LiveResult:
    """What the worker made of `request`: `frame` (`x2video.render.live.LiveFrame`; None when cancelled or failed,
    `error` says which), the tiers it ran under, and `newest`: the newest request's id when this one was taken (equal
    to its own id: no newer request was waiting behind it)."""

    request: LiveRequest
    frame: Any
    choice: Any
    newest: int
    error: str = ""
    done_at: float = 0.0

    @property
    def t(self) -> int:
        return self.request.t

    @property
    def image(self) -> np.ndarray:
        return self.frame.image
