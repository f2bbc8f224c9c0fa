"""X2Video: intrinsic channels to photorealistic video with a video diffusion model (no Qt here).

    import x2video

    shot = x2video.load_shot("my_shot")           # a shot folder, multi-layer EXRs or an XRGB set
    model = x2video.load_model()                  # the shipped weights (or a checkpoint folder)
    edits = x2video.Edits(global_prompt="warm evening light", dropped={"irradiance"})
    with x2video.FrameSink("out.mp4", fps=shot.info.fps) as sink:   # or a folder of EXR frames
        x2video.Renderer(model).render(shot, edits, x2video.RenderSettings(preset="fast"), on_event=sink)

`on_event` receives the typed events of `x2video.render.events` (FramesReady carries finished
frames, keyframes first); a `CancelToken` passed as `cancel` stops the render between steps.

The names below load on first use, so `import x2video` stays cheap (no torch until a model is needed).
"""
from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

__version__ = "0.1.0"

#: public name -> module that defines it
_EXPORTS = {
    "load_shot": "x2video.io.load",
    "load_model": "x2video.weights",
    "shipped_weights": "x2video.weights",
    "Renderer": "x2video.render.renderer",
    "RenderSettings": "x2video.render.settings",
    "CancelToken": "x2video.render.events",
    "Edits": "x2video.edits.model",
    "FrameSink": "x2video.render.frames",
}
__all__ = sorted(_EXPORTS)

if TYPE_CHECKING:
    from x2video.edits.model import Edits as Edits
    from x2video.io.load import load_shot as load_shot
    from x2video.render.events import CancelToken as CancelToken
    from x2video.render.frames import FrameSink as FrameSink
    from x2video.render.renderer import Renderer as Renderer
    from x2video.render.settings import RenderSettings as RenderSettings
    from x2video.weights import load_model as load_model
    from x2video.weights import shipped_weights as shipped_weights


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'x2video' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
