"""What the small nets' training loops share (the tier-1 residual net, `residual_stage`; its difference over a shot's
frames, `difference_stage`; the keyframe fill, `fill_stage`): the display image their losses and PSNRs read, the
learning-rate schedule, one optimiser step, and the wall-clock budget."""
from __future__ import annotations

import math
import time

import torch


def tonemap_t(x: torch.Tensor) -> torch.Tensor:
    """`x2video.channels.tonemap` in torch: clip to [0, 1], sRGB encode."""
    x = x.clamp(0, 1)
    return torch.where(x <= 0.0031308, x * 12.92, 1.055 * x.clamp_min(0.0031308) ** (1 / 2.4) - 0.055)


def warm_cosine(step: int, steps: int) -> float:
    """The learning rate's factor at `step`: 100 linear warm-up steps, then a cosine decay to 5 % at `steps`."""
    return min(1.0, (step + 1) / 100) * (0.05 + 0.95 * 0.5 * (1 + math.cos(math.pi * min(step, steps) / steps)))


def optimiser_step(net: torch.nn.Module, opt: torch.optim.Optimizer, loss: torch.Tensor) -> None:
    """Back-propagate `loss`, clip the gradient norm to 1 and step."""
    opt.zero_grad(set_to_none=True)
    loss.backward()
    torch.nn.utils.clip_grad_norm_(net.parameters(), 1.0)
    opt.step()


def over_budget(t0: float, minutes: float) -> bool:
    """Whether a run started at `t0` (perf_counter) has spent its `minutes` (0: no budget)."""
    return minutes > 0 and (time.perf_counter() - t0) > minutes * 60
