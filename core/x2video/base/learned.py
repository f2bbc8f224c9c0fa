"""The learned keyframe fill (tier 1 of the fill, issue 51): the classical fill corrected by a small network.

The classical fill (`base.fill`, tier 0) carries the keyframes' demodulated shading onto a frame between them; what
it cannot carry is light that changes with the view (glossy reflections, mirrors, glass) and surfaces that no
keyframe saw. The network (`x2video.model.fill_net`) sees what the classical fill was made of (`features`) and
corrects its shading in log space; the frame's own albedo and emission then modulate it back, as in tier 0:

    shading = classical + (level + classical) x expm1(net(features))     (= classical where the net says 0)
    rgb     = shading x albedo + emission                                 the shot's rgb units

All light enters the network in log1p space relative to `level`, the frame's mean classical shading, so it works
at any exposure. The weights ship beside the model's as fill.safetensors + fill.json (`load_learned_fill`).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from x2video.base.fill import FillConfig, FillInputs
from x2video.shot import Shot

#: the network's input planes, in order (`features`); the present flags are those of PRESENT
PLANES = ("warped_a3", "warped_b3", "valid_a", "valid_b", "time_a", "time_b", "gap", "classical3", "holes",
          "albedo3", "normal3", "roughness", "metallic", "emission3", "depth", "irradiance3", "present7", "flow")
#: the G-buffers whose presence the network is told (one flag plane each)
PRESENT = ("albedo", "normal", "roughness", "metallic", "emission", "depth", "irradiance")
#: the number of input planes
N_PLANES = sum(int(p[-1]) if p[-1].isdigit() else 1 for p in PLANES)
#: log depth relative to the frame's median is clipped to this many e-folds
DEPTH_RANGE = 3.0


def light_level(classical: np.ndarray) -> float:
    """The frame's light level: the mean of its classical shading (>= 1e-6), what the network's light is relative to."""
    return max(float(np.maximum(classical, 0).mean()), 1e-6)


def features(shot: Shot, t: int, inputs: FillInputs) -> tuple[np.ndarray, float]:
    """((C, H, W) float32 network input, light level) of frame t, whose classical fill `inputs` made (`PLANES`)."""
    h, w = shot.size
    level = light_level(inputs.shading)
    x = np.zeros((N_PLANES, h, w), np.float32)

    def light(v: np.ndarray) -> np.ndarray:  # (H, W, 3) -> (3, H, W) log1p relative to the level
        return np.log1p(np.maximum(v, 0) / level).transpose(2, 0, 1)

    for i, (s, ok, tw) in enumerate(zip(inputs.warped, inputs.valid, inputs.time_weight)):
        x[3 * i:3 * i + 3] = light(s) * ok[None]
        x[6 + i] = ok
        x[8 + i] = tw
    x[10] = np.log2(abs(inputs.near[1] - inputs.near[0])) / 4 if len(inputs.near) == 2 else 0.0
    x[11:14] = light(inputs.shading)
    x[14] = inputs.holes
    present = []
    for name, sl in (("albedo", slice(15, 18)), ("normal", slice(18, 21)), ("roughness", slice(21, 22)),
                     ("metallic", slice(22, 23))):
        present.append(shot.has(name))
        if shot.has(name):
            v = np.nan_to_num(shot.channel(name, t)).transpose(2, 0, 1)
            x[sl] = v if name == "normal" else np.clip(v, 0, 1)
    present.append(shot.has("emission"))
    if shot.has("emission"):
        x[23:26] = light(np.nan_to_num(shot.channel("emission", t)))
    present.append(shot.has("depth"))
    if shot.has("depth"):
        d = np.nan_to_num(shot.channel("depth", t)[..., 0])
        front = d > 0
        if front.any():
            x[26] = np.where(front, np.clip(np.log(np.maximum(d, 1e-12) / np.median(d[front])), -DEPTH_RANGE, DEPTH_RANGE), 0)
    present.append(shot.has("irradiance"))
    if shot.has("irradiance"):  # the formula, demodulated: the diffuse light in the rgb's units
        x[27:30] = light(np.nan_to_num(shot.channel("irradiance", t)) / max(shot.info.irradiance_scale, 1e-12))
    x[30:37] = np.asarray(present, np.float32)[:, None, None]
    x[37] = inputs.method == "flow"
    return x, level


class LearnedFill:
    """The fill network, ready to correct frames (`fill_frame(..., learned=...)`); `folder` it was loaded from."""

    def __init__(self, net, folder: Path | None = None) -> None:
        if net.cfg.in_channels != N_PLANES:
            raise ValueError(f"{folder or 'the fill network'}: it reads {net.cfg.in_channels} planes, the fill makes {N_PLANES}")
        self.net, self.folder = net, folder

    def shading(self, shot: Shot, t: int, inputs: FillInputs, cfg: FillConfig = FillConfig()) -> np.ndarray:
        """(H, W, 3) frame t's corrected demodulated shading (`fill.fill_frame` modulates it)."""
        import torch

        from x2video.model.fill_net import corrected, correction

        x, level = features(shot, t, inputs)
        with torch.inference_mode():
            delta = correction(self.net, torch.from_numpy(x)[None])  # (1, 3, H, W)
            s = corrected(torch.from_numpy(np.ascontiguousarray(inputs.shading.transpose(2, 0, 1)))[None], level, delta)
        return np.ascontiguousarray(s[0].numpy().transpose(1, 2, 0), dtype=np.float32)


def load_learned_fill(folder: str | Path | None = None) -> LearnedFill:
    """The learned fill from `folder` (fill.safetensors + fill.json), else beside the shipped model's weights;
    FileNotFoundError names the file that is missing."""
    from x2video.model.fill_net import WEIGHTS_FILE, load

    if folder is None:
        from x2video.weights import shipped_weights, where_weights_are_looked_for

        folder = shipped_weights()
        if folder is None:
            raise FileNotFoundError(f"the learned fill needs {WEIGHTS_FILE}: no weights folder found "
                                    f"({where_weights_are_looked_for()}); train it with `x2video train fill`")
    return LearnedFill(load(folder), Path(folder))


def fill_for_tier(tier: int, folder: str | Path | None = None) -> LearnedFill | None:
    """What `fill_frame(learned=...)` takes for a fill tier: None for 0 (classical), the loaded network for 1."""
    if tier == 0:
        return None
    if tier == 1:
        return load_learned_fill(folder)
    raise ValueError(f"fill tier {tier}: 0 (classical) or 1 (learned) here")

