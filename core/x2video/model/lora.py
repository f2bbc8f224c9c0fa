"""Switchable LoRA (paper Sec. Adaptation to Recursive Sampling): one low-rank branch per mode, picked per call.

A small explicit module rather than peft: peft swaps adapters by mutating module state
(`set_adapter`), while the branch here is chosen by each forward call's context, so one
model serves keyframe and every interpolation level in the same process (and threads).
"""
from __future__ import annotations

from typing import Iterable

import torch
import torch.nn.functional as F
from torch import nn


class LoRA(nn.Module):
    """Low-rank update `up(down(x)) * scale`; `up` starts at zero so the branch starts as a no-op."""

    def __init__(self, in_features: int, out_features: int, rank: int, scale: float = 1.0) -> None:
        super().__init__()
        self.down = nn.Linear(in_features, rank, bias=False)
        self.up = nn.Linear(rank, out_features, bias=False)
        self.scale = scale
        nn.init.kaiming_uniform_(self.down.weight, a=5**0.5)
        nn.init.zeros_(self.up.weight)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.up(self.down(x)) * self.scale

    def delta(self) -> torch.Tensor:
        """The update as a dense (out, in) weight: scale * up @ down."""
        return (self.up.weight @ self.down.weight) * self.scale


class SwitchableQKV(nn.Module):
    """q/k/v projections (base weights copied from a self-attention) plus named LoRA branches.

    `q(x, branch)` = `to_q(x) + lora[branch].q(x)`, computed as one linear with the merged
    weight `W + scale * up @ down` (building it costs C*r*C, far below one projection of
    the L*N tokens, so a branch is as cheap as the plain projection); same for k and v.
    """

    def __init__(self, to_q: nn.Linear, to_k: nn.Linear, to_v: nn.Linear, branches: Iterable[str], rank: int, scale: float = 1.0) -> None:
        super().__init__()
        self.to_q = _copy_linear(to_q)
        self.to_k = _copy_linear(to_k)
        self.to_v = _copy_linear(to_v)
        self.lora = nn.ModuleDict()
        for name in branches:
            self.lora[name] = nn.ModuleDict(
                {
                    "q": LoRA(to_q.in_features, to_q.out_features, rank, scale),
                    "k": LoRA(to_k.in_features, to_k.out_features, rank, scale),
                    "v": LoRA(to_v.in_features, to_v.out_features, rank, scale),
                }
            )

    @property
    def branches(self) -> tuple[str, ...]:
        return tuple(self.lora.keys())

    def _branch(self, name: str) -> nn.ModuleDict:
        if name not in self.lora:
            raise KeyError(f"no LoRA branch {name!r} (have {', '.join(self.lora.keys())})")
        return self.lora[name]  # type: ignore[return-value]

    def q(self, x: torch.Tensor, branch: str) -> torch.Tensor:
        return _merged(self.to_q, self._branch(branch)["q"], x)

    def k(self, x: torch.Tensor, branch: str) -> torch.Tensor:
        return _merged(self.to_k, self._branch(branch)["k"], x)

    def v(self, x: torch.Tensor, branch: str) -> torch.Tensor:
        return _merged(self.to_v, self._branch(branch)["v"], x)


def _merged(base: nn.Linear, lora: nn.Module, x: torch.Tensor) -> torch.Tensor:
    """base(x) + lora(x) as a single linear with the merged weight (differentiable in both)."""
    assert isinstance(lora, LoRA)
    return F.linear(x, base.weight + lora.delta().to(base.weight.dtype), base.bias)


def _copy_linear(src: nn.Linear) -> nn.Linear:
    """A new Linear with the same shape, weights and bias as `src` (initialisation from self-attention)."""
    dst = nn.Linear(src.in_features, src.out_features, bias=src.bias is not None)
    dst = dst.to(device=src.weight.device, dtype=src.weight.dtype)
    with torch.no_grad():
        dst.weight.copy_(src.weight)
        if src.bias is not None:
            dst.bias.copy_(src.bias)
    return dst
