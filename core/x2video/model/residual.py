"""Tier 1 of "no more model than a scene needs": one deterministic network pass for what the formula misses.

The formula albedo x irradiance is exact for diffuse light; what a path tracer adds is mostly
the glossy term (reflections, metals, mirrors), emitters and windows (DESIGN.md, "Path-traced
ground truth"). `ResidualNet` predicts that remainder in log space from the five channels, at
full resolution, in one pass:

    y      = log1p(albedo x irradiance) + net(features)   (N, 3, H, W), exposure-normalised units
    output = expm1(y)                                      linear radiance, >= 0

The base is the plain product, not `x2video.model.shading.classical_shading`: its grey-world GGX
term overshoots Cycles' energy-conserving Principled BSDF (on a path-traced test room: 20.9 dB
against the product's 31.7 dB), so the net learns the specular term from the channels instead.
A small pixel-space U-Net (four levels, a global-context vector at the bottom so the light's
colour and level reach every pixel), zero-initialised output, so an untrained net is the
formula. Deterministic and per frame: it cannot flicker more than its inputs.
"""
from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Mapping

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

#: input feature planes, in order (see `features`)
FEATURES = ("albedo3", "normal3", "roughness", "metallic", "log_irradiance3", "log_formula3", "present5", "geometry")
#: where log1p(formula) sits among the input planes (`features`); `apply`'s base
FORMULA_PLANES = slice(11, 14)


@dataclass
class ResidualConfig:
    """Shape of the tier-1 network; stored beside its weights so a checkpoint rebuilds itself."""

    #: feature channels per level, finest first (the net downsamples by 2 between levels)
    widths: tuple[int, ...] = (16, 32, 64, 128)
    #: input planes: 3 + 3 + 1 + 1 + 3 + 3 + 5 present flags + 1 geometry mask
    in_channels: int = 20

    @property
    def factor(self) -> int:
        """Frames are padded to a multiple of this (reflect) and cropped back."""
        return 2 ** (len(self.widths) - 1)


def _block(cin: int, cout: int) -> nn.Sequential:
    return nn.Sequential(nn.Conv2d(cin, cout, 3, padding=1), nn.SiLU(), nn.Conv2d(cout, cout, 3, padding=1), nn.SiLU())


class ResidualNet(nn.Module):
    """features (N, C_in, H, W) -> log-space residual (N, 3, H, W); H, W multiples of `cfg.factor`."""

    def __init__(self, cfg: ResidualConfig | None = None):
        super().__init__()
        self.cfg = cfg = cfg or ResidualConfig()
        w = cfg.widths
        self.down = nn.ModuleList([_block(cfg.in_channels, w[0])] + [_block(w[i - 1], w[i]) for i in range(1, len(w))])
        self.pool = nn.ModuleList([nn.Conv2d(w[i], w[i], 2, stride=2) for i in range(len(w) - 1)])
        self.context = nn.Linear(w[-1], w[-1])
        self.up = nn.ModuleList([_block(w[i + 1] + w[i], w[i]) for i in range(len(w) - 1)])
        self.out = nn.Conv2d(w[0], 3, 1)
        nn.init.zeros_(self.out.weight)
        nn.init.zeros_(self.out.bias)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        skips = []
        for i, block in enumerate(self.down):
            x = block(x)
            if i < len(self.pool):
                skips.append(x)
                x = self.pool[i](x)
        g = self.context(x.mean((2, 3)))  # (N, C) global context: the light's level and colour
        x = x + g[:, :, None, None]
        for i in reversed(range(len(self.up))):
            x = F.interpolate(x, scale_factor=2, mode="bilinear", align_corners=False)
            x = self.up[i](torch.cat([x, skips[i]], 1))
        return self.out(x)


def _finite(v: np.ndarray) -> np.ndarray:
    """float32 `v` with NaN and +-Inf set to 0 (what the loaders do with them, `x2video.io.convention.zero_nonfinite`)."""
    v = np.asarray(v, np.float32)
    return v if np.isfinite(v).all() else np.where(np.isfinite(v), v, np.float32(0))


def _frame_shape(ch: Mapping[str, np.ndarray | None], shape: tuple[int, int] | None) -> tuple[int, int]:
    present = [np.asarray(v).shape[:2] for v in ch.values() if v is not None]
    if present:
        return present[0]
    if shape is None:
        raise ValueError("every channel is dropped: give the frame's (H, W) as `shape`")
    return tuple(shape)[:2]  # type: ignore[return-value]


def formula(ch: Mapping[str, np.ndarray | None], shape: tuple[int, int] | None = None) -> np.ndarray:
    """(H, W, 3) albedo x irradiance (zeros when either is missing; `shape` = (H, W) when every channel is):
    tier 0 and the net's base. Non-finite values count as 0, albedo is clipped to [0, 1], irradiance to >= 0."""
    al, ir = ch.get("albedo"), ch.get("irradiance")
    if al is None or ir is None:
        return np.zeros((*_frame_shape(ch, shape), 3), np.float32)
    return (np.clip(_finite(al), 0, 1) * np.maximum(_finite(ir), 0)).astype(np.float32)


def features(ch: Mapping[str, np.ndarray | None], shape: tuple[int, int] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(C_in, H, W) network input and (3, H, W) linear formula (albedo x irradiance) of one frame's channels
    (memory convention, irradiance exposure-normalised). A dropped channel is zeros with its present flag 0;
    `shape` = (H, W) is needed only when every channel is dropped. Non-finite values count as 0 (one NaN
    would otherwise reach the net's global context and blank the whole frame); roughness and metallic are
    clamped to [0, 1]."""
    h, w = _frame_shape(ch, shape)

    def get(name: str, n: int) -> tuple[np.ndarray, float]:
        v = ch.get(name)
        if v is None:
            return np.zeros((h, w, n), np.float32), 0.0
        v = _finite(v)
        return (v if v.ndim == 3 else v[..., None])[..., :n], 1.0

    al, pa = get("albedo", 3)
    nr, pn = get("normal", 3)
    ro, pr = get("roughness", 1)
    me, pm = get("metallic", 1)
    ro, me = np.clip(ro, 0, 1), np.clip(me, 0, 1)  # their range, as the loaders and the sampler's to_vae_range clamp them
    ir, pi = get("irradiance", 3)
    shading = formula(ch, (h, w))
    geometry = (np.linalg.norm(nr, axis=-1, keepdims=True) > 0.5).astype(np.float32) if pn else np.ones((h, w, 1), np.float32)
    present = np.broadcast_to(np.array([pa, pn, pr, pm, pi], np.float32), (h, w, 5))
    x = np.concatenate([al, nr, ro, me, np.log1p(np.maximum(ir, 0)), np.log1p(np.maximum(shading, 0)), present, geometry], -1)
    return np.ascontiguousarray(x.transpose(2, 0, 1)), np.ascontiguousarray(shading.transpose(2, 0, 1))


def apply(net, x: torch.Tensor, shading: torch.Tensor) -> torch.Tensor:
    """Linear radiance (N, 3, H, W) from features and the formula (`features`' second output) of any size
    (reflect-padded to the net's factor, cropped back)."""
    h, w = x.shape[-2:]
    f = net.cfg.factor  # an OnnxResidual carries the same cfg
    ph, pw = (-h) % f, (-w) % f
    xp = F.pad(x, (0, pw, 0, ph), mode="reflect" if min(h, w) > max(ph, pw) else "replicate") if ph or pw else x
    delta = net(xp)[..., :h, :w]
    return torch.expm1(torch.log1p(shading.clamp_min(0)) + delta).clamp_min(0)


def save(net: ResidualNet, folder: str | Path, extra: dict | None = None) -> Path:
    """fp16 safetensors + residual.json (config and what trained it) in `folder`."""
    from safetensors.torch import save_file

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    from x2video.io.atomic import atomic_path, write_json_atomic

    with atomic_path(folder / "residual.safetensors") as tmp:
        save_file({k: v.detach().to(torch.float16).contiguous() for k, v in net.state_dict().items()}, str(tmp))
    cfg = asdict(net.cfg)
    write_json_atomic(folder / "residual.json", {"config": cfg, **(extra or {})})
    return folder / "residual.safetensors"


def load(folder: str | Path, device: str | torch.device = "cpu") -> ResidualNet:
    """The tier-1 net saved in `folder` by `save` (float32 on `device`, eval mode)."""
    from safetensors.torch import load_file

    folder = Path(folder)
    meta = folder / "residual.json"
    if not meta.is_file():
        raise FileNotFoundError(f"{meta}: no tier-1 residual network here (train one with `x2video train residual`)")
    cfg = json.loads(meta.read_text())["config"]
    net = ResidualNet(ResidualConfig(widths=tuple(cfg["widths"]), in_channels=int(cfg["in_channels"])))
    state = load_file(str(folder / "residual.safetensors"))
    net.load_state_dict({k: v.float() for k, v in state.items()})
    return net.to(device).eval()


class OnnxResidual:
    """The tier-1 net run by ONNX Runtime (several times faster than PyTorch on a CPU for this conv stack),
    exported from the PyTorch net when loaded; called like the net: features (N, C_in, H, W) -> delta.
    PyTorch stays the reference: `tests/test_tiers.py` checks the two agree."""

    def __init__(self, net: ResidualNet, threads: int | None = None):
        import io

        import onnxruntime as ort

        self.cfg = net.cfg
        buf = io.BytesIO()
        x = torch.zeros(1, net.cfg.in_channels, 8 * net.cfg.factor, 8 * net.cfg.factor)
        axes = {0: "n", 2: "h", 3: "w"}
        with torch.no_grad():
            torch.onnx.export(net.float().cpu().eval(), (x,), buf, input_names=["features"], output_names=["delta"],
                              dynamic_axes={"features": axes, "delta": axes}, opset_version=17, dynamo=False)
        so = ort.SessionOptions()
        so.intra_op_num_threads = int(threads or torch.get_num_threads())
        so.log_severity_level = 3
        self.session = ort.InferenceSession(buf.getvalue(), so, providers=["CPUExecutionProvider"])

    def __call__(self, x: torch.Tensor) -> torch.Tensor:
        out = self.session.run(None, {"features": x.detach().float().cpu().numpy()})[0]
        return torch.from_numpy(out).to(x.device)


def engine(net: ResidualNet, device: torch.device | str = "cpu", prefer: str = "auto"):
    """What runs the net for rendering: ONNX Runtime on a CPU when it is installed ("auto"/"onnx"), else the
    PyTorch module ("torch", or any CUDA device)."""
    if prefer not in ("auto", "onnx", "torch"):
        raise ValueError(f"unknown tier-1 engine {prefer!r} (auto, onnx, torch)")
    if prefer == "torch" or torch.device(device).type != "cpu":
        return net
    try:
        return OnnxResidual(net)
    except ImportError:
        if prefer == "onnx":
            raise
        return net
