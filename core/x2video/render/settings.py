"""`RenderSettings`: how a shot is rendered, declared once: the CLI's flags (`x2video.fields`), the editor's
panel, the farm's job templates and the `Renderer` all read these fields."""
from __future__ import annotations

import dataclasses
import functools
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Literal

if TYPE_CHECKING:
    from x2video.model.api import RenderModel
    from x2video.shot import Shot


@functools.cache
def _hints(cls: type) -> dict[str, Any]:
    import typing

    return typing.get_type_hints(cls)


@dataclass
class RenderSettings:
    """How to sample a shot. The field docstrings are the CLI help (`x2video.fields`); why each
    default is what it is, measured, is in docs/evaluations/ (the notebook and the entries it cites)."""

    sampler: Literal["ddim", "lcm"] = "ddim"
    """DDIM (v-prediction, trailing spacing) or LCM multistep (needs distilled weights); ignored with a preset."""
    steps: int = 20
    """Denoising steps per window (paper: DDIM-20; LCM-2 after distillation); ignored with a preset."""
    seed: int = 0
    """Seed of the initial noise; same inputs and seed give identical frames."""
    window: int = 5
    """Frames per window N (the paper trains with N=5)."""
    scheme: Literal["recursive", "sequential"] = "recursive"
    """Recursive Sampling (keyframes, then interpolation levels) or the sequential baseline."""
    frames: tuple[int, int] | None = None
    """Render only frames [START, STOP) of the shot."""
    detail: bool = True
    """Residual models only: add back the classical shading's fine detail that the VAE loses (off: an ablation)."""
    replace_refs: bool = True
    """Between denoising steps, hold each window's reference frames (those earlier windows produced) at their
    latent noised to the step's level, as in training, instead of letting the window re-estimate them
    (`x2video.sampling.samplers.Known`); off is the ablation."""
    seams: bool = True
    """The seam pass, recursive scheme with three levels or more (18 frames or more at N = 5): after the first
    interpolation level, make each keyframe again with its neighbours in a window of that level
    (`x2video.sampling.planner.seam_windows`), so the finer levels interpolate between frames that agree. One
    more window per keyframe; the frames it makes again arrive twice (`FramesReady.replaces`)."""
    max_levels: int | None = None
    """Recursive scheme only: at most this many levels K (unset: the fewest that let one keyframe window span the
    shot; K = 3 at 65 frames and N = 5). Fewer levels put the keyframes (N-1)^(K-1) frames apart and chain the
    keyframe windows (`x2video.sampling.planner.plan_recursive`); K = 1 is sequential sampling in keyframe mode."""
    noise: Literal["window", "frame"] = "frame"
    """How the initial noise is seeded: per 'frame' of the shot (a frame has the same noise in every window that
    holds it, a reference is re-noised with the noise it was made from, and a sub-range renders with the same
    noise; `frame_noise`), or per 'window' (each window draws its own noise for all its positions)."""
    noise_shared: float = 0.95
    """With 'frame' noise: the fraction of the noise's variance every frame of the shot shares, in [0, 1] (a
    mixed noise prior, Ge et al. 2023, "Preserve Your Own Correlation"); each frame's noise stays standard
    normal; 0 gives independent per-frame noise. Higher values trade a little PSNR for temporal consistency."""
    ref_dc: float = 1.0
    """Interpolation windows, where a frame's lighting must be inferred (the whole frame without albedo or
    irradiance, else inside its A|M|R mask): at every denoising step pull that region's latent mean per
    channel (its colour and brightness) this fraction of the way, in [0, 1], to the linear interpolation of
    the two references' means (statistics matching to the keyframes, as AdaIN on latents in Rerender-A-Video,
    Yang et al. 2023), so that windows agree on the lighting across seams; 0: off."""
    resample: int = 1
    """DDIM only: RePaint's resampling (Lugmayr et al. 2022) in windows that hold references: each denoising
    step but the first and last is taken this many times, going back one step's worth of noise in between
    (`x2video.sampling.samplers.sample_ddim`); 1: off; r costs those windows about r times the network passes."""
    quality: Literal["auto", "formula", "residual", "diffusion"] = "auto"
    """Which tier renders (`x2video.tiers.registry`): 'formula' = albedo x irradiance, no network, no weights;
    'residual' = one pass of the tier-1 network over it (needs residual.safetensors beside the weights);
    'diffusion' = the video diffusion sampler. 'auto': the tier-1 network where nothing must be generated, the
    diffusion sampler where something must (a dropped channel, a masked A|M|R region, a local prompt, a
    reference) and, when only some regions must be generated, tier 1 around them, the seam feathered inside the regions; a model
    without the tier-1 network renders with the diffusion sampler. The log says what ran and why."""
    base: Literal["auto", "off"] = "auto"
    """Where the shot carries its own path-traced rgb (on every frame, or on keyframes): 'auto' keeps it as the base
    (`x2video.base.stage`): a frame no edit reaches is the shot's rgb, bit for bit in the input's units (a frame
    between keyframes: filled from its nearest keyframes, `x2video.base.fill`), and an edit renders as the tier's
    difference over it, base + R(edited) - R(original), inside the edit's reach only; no tier runs, and no model is
    needed, without edits. 'off': every frame re-rendered from the channels by the tier, as before the base existed
    (what scoring a tier against the shot's own rgb needs)."""
    fill: Literal["classical", "diffusion"] = "classical"
    """With base 'auto', how a keyframe shot's frames between its keyframes are made: 'classical' fills them from their
    nearest keyframes by reprojection (`x2video.base.fill`); 'diffusion' renders them with the diffusion tier, every
    keyframe's path-traced frame a reference at the ends of its interpolation windows (the paper's Ref-Keyframe:
    `x2video.sampling.planner.plan_keyframed`), the keyframes kept bit for bit. 'diffusion' needs a model, quality
    'auto' or 'diffusion', and no edits (they would change what the keyframes show)."""
    keyframes: str | None = None
    """Keep the shot's rgb on these frames only: 'every:N' (frames 0, N, 2N, ... and the last) or a list '0,8,20';
    with base 'auto' the frames between are filled from them (`x2video.base.keyframes`), so a fully rendered shot
    scores the fill against its own rgb. Unset: every frame that carries rgb."""
    exposure: float | str = "auto"
    """MP4 exposure in stops on the input's radiometric units, or 'auto': the shot's own irradiance
    normalisation, i.e. what the model saw (`x2video.io.units.OutputUnits`). EXR output is always in the
    input's units."""
    engine: Literal["auto", "torch", "onnx", "openvino"] = "auto"
    """What runs the diffusion tier's UNet, VAE decoder and channel encoder (`x2video.model.engine`): 'torch'
    (PyTorch, the reference), 'onnx' (ONNX Runtime) or 'openvino' (OpenVINO) on graphs exported once per
    window and frame size and cached under the user's cache folder; 'auto': the fastest installed on a CPU
    (OpenVINO, then ONNX Runtime), PyTorch on a GPU or in half precision."""
    preset: Literal["fast", "quality"] | None = None
    """Overrides sampler and steps when set: 'fast' = LCM-2 if distilled weights are loaded, else DDIM-4;
    'quality' = DDIM-20 (`x2video.render.settings.select_steps`)."""
    guess_unseen: bool = False
    """Tier 1: let the net guess the light where the channels hold none (sky and backdrops through windows, what
    shows through clear glass); its guess follows its training rooms, mostly daylight. Off: the formula there
    (black unless the channels light it), never a daylight sky painted into a night window."""
    working_pixels: int = 320 * 224
    """Diffusion tier, large frames: a frame with more pixels than this runs the diffusion network at a working
    resolution of at most this many pixels (aspect kept), near the size it was trained at, and the network's
    residual over the formula (log space) comes back to full size on top of the full-resolution formula, whose
    detail so stays full resolution (`x2video.conditioning.network`). 0: always at full resolution (memory and time
    grow with the frame)."""
    residual_pixels: int = 512 * 512
    """Tier 1, large frames: a frame with more pixels than this runs the tier-1 net at a working resolution of at
    most this many pixels (aspect kept) and its log-space correction of the formula comes back to full size,
    bilinearly, on top of the full-resolution formula (`x2video.tiers.residual.residual_frames`). On 1024x1024
    Cycles frames it scored about what the full-size pass scores (21.06 dB against 21.07, the formula 19.09), 3.0x faster there and
    4.4x at 1920x1080 (docs/SHOT_FORMAT.md). 0: the net at full resolution, in overlapping tiles beyond 896x896."""

    def __post_init__(self) -> None:
        self.validate()  # `RenderSettings(steps=0)` and `dataclasses.replace(s, steps=0)` fail where they are written

    def validate(self) -> "RenderSettings":
        """Check every field on its own (the model and the shot are not needed), before any tier is chosen: a value no
        tier accepts is refused by all, even by the tiers that do not read it (`--steps 0` under quality 'formula').
        ValueError naming the field and its value; returns self. It runs when the settings are made (`__post_init__`:
        the CLI's flags, the farm's jobs, the editor's panel, the Python API); call it again after changing a field in
        place. What depends on the shot (a frame range past its end) or the model (LCM without distilled weights) is
        checked where those are known."""
        import math
        import numbers
        import typing

        hints = _hints(type(self))
        for name, tp in hints.items():
            if name == "quality":  # any registered tier (`x2video.tiers.base.TIERS`, which the Literal only lists the built-in
                continue  # ones of): `tiers.decide` refuses an unknown one before it chooses
            value = getattr(self, name)
            options = [a for a in typing.get_args(tp) if a is not type(None)]
            if typing.get_origin(tp) is Literal or (options and all(typing.get_origin(o) is Literal for o in options)):
                allowed = [v for o in (options if typing.get_origin(tp) is not Literal else [tp]) for v in typing.get_args(o)]
                if type(None) in typing.get_args(tp) and value is None:
                    continue
                if value not in allowed:
                    label = {"noise": "noise seeding", "scheme": "sampling scheme", "preset": "render preset"}.get(name, name)
                    raise ValueError(f"unknown {label} {value!r} (use {', '.join(map(repr, allowed[:-1]))} or {allowed[-1]!r})")
            elif tp is int or (tp is not bool and int in options and value is not None):
                if isinstance(value, bool) or not isinstance(value, numbers.Integral):
                    raise ValueError(f"{name}: expected an integer, got {value!r}")
            elif tp is float:
                if isinstance(value, bool) or not isinstance(value, numbers.Real) or not math.isfinite(value):
                    raise ValueError(f"{name}: expected a finite number, got {value!r}")
        if self.steps < 1:
            raise ValueError(f"steps must be at least 1, got {self.steps} (under every quality, also where a tier takes no steps)")
        if self.window < 2:
            raise ValueError(f"window size must be at least 2 frames, got {self.window}")
        if self.resample < 1:
            raise ValueError(f"resample must be at least 1 (1 = off), got {self.resample}")
        if self.seed < 0:
            raise ValueError(f"seed must be 0 or more, got {self.seed}")
        for name in ("working_pixels", "residual_pixels"):
            if getattr(self, name) < 0:
                raise ValueError(f"{name} must be 0 (full resolution) or more, got {getattr(self, name)}")
        if not 0.0 <= self.noise_shared <= 1.0:
            raise ValueError(f"noise_shared must lie in [0, 1], got {self.noise_shared}")
        if not 0.0 <= self.ref_dc <= 1.0:
            raise ValueError(f"ref_dc must lie in [0, 1] (0 = off), got {self.ref_dc}")
        if self.max_levels is not None and self.max_levels < 1:
            raise ValueError(f"max_levels must be at least 1 (unset: as many as the shot needs), got {self.max_levels}")
        if self.frames is not None:
            if (not isinstance(self.frames, (tuple, list)) or len(self.frames) != 2
                    or not all(isinstance(v, numbers.Integral) and not isinstance(v, bool) for v in self.frames)):
                raise ValueError(f"frames: expected (START, STOP) integers, got {self.frames!r}")
            start, stop = self.frames
            if start < 0:
                raise ValueError(f"frames: START must be 0 or more, got {start}:{stop}")
            if stop <= start:
                raise ValueError(f"frames: the range {start}:{stop} is empty (STOP must be greater than START)")
        if self.keyframes is not None:
            from x2video.base.keyframes import check_keyframes

            check_keyframes(self.keyframes)  # ValueError naming --keyframes; the frames' range is checked against the shot
        if isinstance(self.exposure, str):
            if self.exposure != "auto":
                from x2video.io.units import parse_exposure

                parse_exposure(self.exposure)  # ValueError naming it
        elif isinstance(self.exposure, bool) or not isinstance(self.exposure, numbers.Real) or not math.isfinite(self.exposure):
            raise ValueError(f"exposure: expected 'auto' or a finite number of stops, got {self.exposure!r}")
        return self


def frame_range(shot: Shot, settings: RenderSettings) -> tuple[int, int]:
    """[start, stop) of the shot a render with `settings` covers (`RenderSettings.frames`, default all)."""
    start, stop = settings.frames if settings.frames is not None else (0, shot.num_frames)
    if not 0 <= start < stop <= shot.num_frames:
        raise ValueError(f"frame range [{start}, {stop}) outside the shot's {shot.num_frames} frames")
    return start, stop


def select_steps(settings: RenderSettings, model: RenderModel | None) -> RenderSettings:
    """Resolve `settings.preset` into a sampler and step count for this model.

    'fast': LCM-2 when the model has distilled (LCM) weights, else DDIM-4; 'quality': DDIM-20;
    None: the settings as given. `model` None (not built yet): as a model without LCM weights.
    """
    if settings.preset is None:
        return settings
    if settings.preset == "fast":
        sampler, steps = ("lcm", 2) if model is not None and model.has_lcm else ("ddim", 4)
    elif settings.preset == "quality":
        sampler, steps = "ddim", 20
    else:
        raise ValueError(f"unknown render preset {settings.preset!r} (use 'fast' or 'quality')")
    return dataclasses.replace(settings, sampler=sampler, steps=steps)


def check_pixel_bounds(settings: RenderSettings) -> None:
    for name in ("working_pixels", "residual_pixels"):
        if getattr(settings, name) < 0:
            raise ValueError(f"{name} must be 0 (full resolution) or more, got {getattr(settings, name)}")


def resolve(settings: RenderSettings, model: RenderModel | None) -> RenderSettings:
    """`settings` with the preset resolved for `model` (`select_steps`), every bound checked (ValueError names it)."""
    settings = select_steps(settings, model)
    if settings.sampler not in ("ddim", "lcm"):
        raise ValueError(f"unknown sampler {settings.sampler!r} (use 'ddim' or 'lcm')")
    if settings.sampler == "lcm" and model is not None and not model.has_lcm:
        raise ValueError("sampler 'lcm' needs distilled LCM weights, and the loaded model has none")
    if settings.steps < 1:
        raise ValueError(f"steps must be at least 1, got {settings.steps}")
    if settings.noise not in ("window", "frame"):
        raise ValueError(f"unknown noise seeding {settings.noise!r} (use 'window' or 'frame')")
    if not 0.0 <= settings.noise_shared <= 1.0:
        raise ValueError(f"noise_shared must lie in [0, 1], got {settings.noise_shared}")
    if not 0.0 <= settings.ref_dc <= 1.0:
        raise ValueError(f"ref_dc must lie in [0, 1] (0 = off), got {settings.ref_dc}")
    if settings.resample < 1:
        raise ValueError(f"resample must be at least 1 (1 = off), got {settings.resample}")
    check_pixel_bounds(settings)
    return settings
