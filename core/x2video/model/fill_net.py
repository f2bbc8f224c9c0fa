"""The learned keyframe fill's network (tier 1 of the fill, issue 51): a small U-Net that corrects the classical fill.

Its input is what `x2video.base.learned.features` makes of a frame between keyframes: the two keyframes' shading
warped onto it with its validity and time weights, the classical fill's shading, the frame's own G-buffers and,
when the shot has it, its irradiance (the formula, demodulated), all light in log space relative to the frame's
light level. Its output is a log-space correction of the classical fill's demodulated shading (`corrected`). The
last layer starts at zero, so an untrained net is the classical fill, exactly.
"""
from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path

import torch
from torch import nn
from torch.nn import functional as F

#: the weights' file names in a weights folder (beside the model's, `resources/x2video-tiny/`)
WEIGHTS_FILE, META_FILE = "fill.safetensors", "fill.json"


@dataclass
class FillNetConfig:
    """Shape of the fill network; stored beside its weights so a checkpoint rebuilds itself."""

    #: input planes (`x2video.base.learned.PLANES`)
    in_channels: int
    #: feature channels per level, finest first (the net downsamples by 2 between levels)
    widths: tuple[int, ...] = (16, 32, 64)

    @property
    def factor(self) -> int:
        """Frames are padded to a multiple of this (reflect) and cropped back."""
        return 2 ** len(self.widths)


def _block(cin: int, cout: int) -> nn.Sequential:
    return nn.Sequential(nn.Conv2d(cin, cout, 3, padding=1), nn.SiLU(), nn.Conv2d(cout, cout, 3, padding=1), nn.SiLU())


class FillNet(nn.Module):
    """features (N, C_in, H, W) -> log-space correction of the shading (N, 3, H, W); H, W multiples of `cfg.factor`.

    The U-Net runs at half resolution (a strided stem in, a pixel shuffle out: each cell predicts its 2 x 2 pixels),
    which costs a quarter of a full-resolution one; the classical fill it corrects keeps the full-resolution detail."""

    def __init__(self, cfg: FillNetConfig):
        super().__init__()
        self.cfg = cfg
        w = cfg.widths
        self.stem = nn.Sequential(nn.Conv2d(cfg.in_channels, w[0], 3, stride=2, padding=1), nn.SiLU())
        self.down = nn.ModuleList([_block(w[0], w[0])] + [_block(w[i - 1], w[i]) for i in range(1, len(w))])
        self.pool = nn.ModuleList([nn.Conv2d(w[i], w[i], 2, stride=2) for i in range(len(w) - 1)])
        self.context = nn.Linear(w[-1], w[-1])
        self.up = nn.ModuleList([_block(w[i + 1] + w[i], w[i]) for i in range(len(w) - 1)])
        self.out = nn.Conv2d(w[0], 3 * 4, 1)
        nn.init.zeros_(self.out.weight)  # an untrained net leaves the classical fill as it is
        nn.init.zeros_(self.out.bias)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = self.stem(x)  # (N, w[0], H / 2, W / 2)
        skips = []
        for i, block in enumerate(self.down):
            x = block(x)
            if i < len(self.pool):
                skips.append(x)  # (N, w[i], H / 2^(i+1), W / 2^(i+1))
                x = self.pool[i](x)
        x = x + self.context(x.mean((2, 3)))[:, :, None, None]  # the frame's global context (its light), at every cell
        for i in reversed(range(len(self.up))):
            x = F.interpolate(x, scale_factor=2, mode="bilinear", align_corners=False)
            x = self.up[i](torch.cat([x, skips[i]], 1))
        return F.pixel_shuffle(self.out(x), 2)  # (N, 12, H / 2, W / 2) -> (N, 3, H, W)


def correction(net: FillNet, x: torch.Tensor) -> torch.Tensor:
    """The net's correction (N, 3, H, W) for features x of any size (padded to the net's factor, cropped back)."""
    h, w = x.shape[-2:]
    f = net.cfg.factor
    ph, pw = (-h) % f, (-w) % f
    xp = F.pad(x, (0, pw, 0, ph), mode="reflect" if min(h, w) > max(ph, pw) else "replicate") if ph or pw else x
    return net(xp)[..., :h, :w]


#: the correction is clamped to this many e-folds either way (a wild early step cannot overflow the shading)
MAX_LOG_CORRECTION = 8.0


def corrected(shading: torch.Tensor, level: torch.Tensor, delta: torch.Tensor) -> torch.Tensor:
    """The classical fill's `shading` with the net's log-space correction `delta`: log1p(s / level) + delta, written
    so that delta = 0 gives `shading` back bit for bit. `level` broadcasts: (N, 1, 1, 1) or a number."""
    d = delta.clamp(-MAX_LOG_CORRECTION, MAX_LOG_CORRECTION)
    return shading + (level + shading.clamp_min(0)) * torch.expm1(d)


def save(net: FillNet, folder: str | Path, extra: dict | None = None) -> Path:
    """fp16 `fill.safetensors` + `fill.json` (config and what trained it) in `folder`."""
    from safetensors.torch import save_file

    from x2video.io.atomic import atomic_path, write_json_atomic

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    with atomic_path(folder / WEIGHTS_FILE) as tmp:
        save_file({k: v.detach().to(torch.float16).contiguous() for k, v in net.state_dict().items()}, str(tmp))
    write_json_atomic(folder / META_FILE, {"config": asdict(net.cfg), **(extra or {})})
    return folder / WEIGHTS_FILE


def load(folder: str | Path, device: str | torch.device = "cpu") -> FillNet:
    """The fill network saved in `folder` by `save` (float32 on `device`, eval mode); FileNotFoundError names the
    missing file."""
    from safetensors.torch import load_file

    folder = Path(folder)
    for name in (WEIGHTS_FILE, META_FILE):
        if not (folder / name).is_file():
            raise FileNotFoundError(f"{folder / name} is missing: no learned keyframe fill there "
                                    "(train one with `x2video train fill`, then copy fill.safetensors and fill.json there)")
    cfg = json.loads((folder / META_FILE).read_text())["config"]
    net = FillNet(FillNetConfig(in_channels=int(cfg["in_channels"]), widths=tuple(int(w) for w in cfg["widths"])))
    net.load_state_dict({k: v.float() for k, v in load_file(str(folder / WEIGHTS_FILE)).items()})
    return net.to(device).eval()
