"""The tier-1 net's engines: ONNX Runtime where it is faster than PyTorch (`engine`), and the net's weights digest.

Split from `x2video.model.residual` (the net, its features and its tiled application), which these run.
"""
from __future__ import annotations

import hashlib

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

from x2video.model.residual import ResidualNet


class OnnxResidual:
    """The tier-1 net run by ONNX Runtime (several times faster than PyTorch on a CPU for this conv stack),
    exported from the PyTorch net when loaded; called like the net: features (N, C_in, H, W) [and a global
    context (N, C)] -> delta, with `bottom` and `context_vector` for `apply_tiled` (their graphs exported
    on first use). PyTorch stays the reference: `tests/test_tiers.py` checks the two agree."""

    def __init__(self, net: ResidualNet, threads: int | None = None):
        import onnxruntime  # noqa: F401  (ImportError here: `engine` falls back to PyTorch)

        self.cfg = net.cfg
        self._net = net.float().cpu().eval()
        self._threads = int(threads or torch.get_num_threads())
        size = 8 * net.cfg.factor
        self.session = self._session(self._export(_Unconcatenated(self._net), (torch.zeros(1, net.cfg.in_channels, size, size),), ["features"], "delta"))
        self._tile_session = self._bottom_session = None  # made on the first tiled frame (`apply_tiled`)
        self._part_session = None  # made on the first box of a frame (`x2video.base.tier1`)
        self._run_options = None

    @property
    def module(self) -> ResidualNet:
        """The PyTorch net this session was exported from."""
        return self._net

    def _session(self, model: bytes):
        from x2video.model.engine import ort_session

        return ort_session(model, self._threads, arena=True)

    def _run(self, session, feed: dict[str, np.ndarray]) -> list[np.ndarray]:
        """`session`'s outputs for `feed`, its memory arena handed back at the end (`engine.arena_released`)."""
        if self._run_options is None:
            from x2video.model.engine import arena_released

            self._run_options = arena_released()
        return session.run(None, feed, self._run_options)

    def _export(self, module: nn.Module, inputs: tuple, names: list[str], output: str | list[str]) -> bytes:
        import io

        buf = io.BytesIO()
        axes = {0: "n", 2: "h", 3: "w"}
        outputs = [output] if isinstance(output, str) else output
        dynamic = {names[0]: axes, outputs[0]: axes, **{k: {0: "n"} for k in [*names[1:], *outputs[1:]]}}
        with torch.no_grad():
            torch.onnx.export(module, inputs, buf, input_names=names, output_names=outputs,
                              dynamic_axes=dynamic, opset_version=17, dynamo=False)
        return buf.getvalue()

    def __call__(self, x: torch.Tensor, g: torch.Tensor | None = None) -> torch.Tensor:
        feed = {"features": x.detach().float().cpu().numpy()}
        if g is None:
            out = self._run(self.session, feed)[0]
        else:
            if self._tile_session is None:
                size = 8 * self.cfg.factor
                self._tile_session = self._session(self._export(_WithContext(_Unconcatenated(self._net)), (torch.zeros(1, self.cfg.in_channels, size, size),
                                                                torch.zeros(1, self.cfg.widths[-1])), ["features", "context"], "delta"))
            feed["context"] = g.detach().float().cpu().numpy()
            out = self._run(self._tile_session, feed)[0]
        return torch.from_numpy(out).to(x.device)

    def bottom(self, x: torch.Tensor) -> torch.Tensor:
        if self._bottom_session is None:
            size = 8 * self.cfg.factor
            self._bottom_session = self._session(self._export(_Bottom(_Unconcatenated(self._net)), (torch.zeros(1, self.cfg.in_channels, size, size),),
                                                              ["features"], "bottom"))
        out = self._run(self._bottom_session, {"features": x.detach().float().cpu().numpy()})[0]
        return torch.from_numpy(out).to(x.device)

    def forward_part(self, x: torch.Tensor, others: torch.Tensor, cells: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """`ResidualNet.forward_part` (a box of a larger frame)."""
        if self._part_session is None:
            size = 8 * self.cfg.factor
            self._part_session = self._session(self._export(_Part(_Unconcatenated(self._net)), (torch.zeros(1, self.cfg.in_channels, size, size),
                                                            torch.zeros(1, self.cfg.widths[-1]), torch.ones(1, 1)),
                                                            ["features", "others", "cells"], ["delta", "bottom_sum"]))
        feed = {"features": x.detach().float().cpu().numpy(), "others": others.detach().float().cpu().numpy(),
                "cells": cells.detach().float().cpu().numpy()}
        delta, s = self._run(self._part_session, feed)
        return torch.from_numpy(delta).to(x.device), torch.from_numpy(s).to(x.device)

    def context_vector(self, mean: torch.Tensor) -> torch.Tensor:
        with torch.inference_mode():
            return self._net.context_vector(mean.float().cpu()).to(mean.device)


class _Unconcatenated(ResidualNet):
    """`ResidualNet` as its graphs are exported: each decoder block's first conv, which reads the upsampled coarser
    features and the skip concatenated, is two convs summed, one on each (the same products summed in another order:
    equal to float precision). ONNX Runtime's CPU provider copies a concatenation out of its blocked layout and back:
    on a 320x224 frame the three cost about 3 ms of the net's 58, the split convs about 1. Made from the net's weights
    as they are when a graph is exported."""

    def __init__(self, net: ResidualNet):
        nn.Module.__init__(self)
        self.cfg = net.cfg
        self.down, self.pool, self.context, self.up, self.out = net.down, net.pool, net.context, net.up, net.out
        self.coarse, self.skip = nn.ModuleList(), nn.ModuleList()
        for i, block in enumerate(net.up):
            conv, c = block[0], net.cfg.widths[i + 1]  # reads (upsampled features of width c, skip)
            coarse = nn.Conv2d(c, conv.out_channels, 3, padding=1)
            skip = nn.Conv2d(conv.in_channels - c, conv.out_channels, 3, padding=1, bias=False)
            with torch.no_grad():
                coarse.weight.copy_(conv.weight[:, :c])
                coarse.bias.copy_(conv.bias)
                skip.weight.copy_(conv.weight[:, c:])
            self.coarse.append(coarse)
            self.skip.append(skip)

    def decode(self, skips: list[torch.Tensor], x: torch.Tensor, g: torch.Tensor) -> torch.Tensor:
        """`ResidualNet.decode` without the concatenations."""
        x = x + g[:, :, None, None]
        for i in reversed(range(len(self.up))):
            x = F.interpolate(x, scale_factor=2, mode="bilinear", align_corners=False)
            x = self.up[i][1:](self.coarse[i](x) + self.skip[i](skips[i]))
        return self.out(x)


class _WithContext(nn.Module):
    """ONNX export of `ResidualNet.forward` with the global context given (a tile of a larger frame)."""

    def __init__(self, net: ResidualNet):
        super().__init__()
        self.net = net

    def forward(self, x: torch.Tensor, g: torch.Tensor) -> torch.Tensor:
        return self.net(x, g)


class _Part(nn.Module):
    """ONNX export of `ResidualNet.forward_part` (a box of a larger frame)."""

    def __init__(self, net: ResidualNet):
        super().__init__()
        self.net = net

    def forward(self, x: torch.Tensor, others: torch.Tensor, cells: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return self.net.forward_part(x, others, cells)


class _Bottom(nn.Module):
    """ONNX export of `ResidualNet.bottom`."""

    def __init__(self, net: ResidualNet):
        super().__init__()
        self.net = net

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.net.bottom(x)


def torch_module(net) -> ResidualNet:
    """The PyTorch net behind `net` (a `ResidualNet`, or what `engine` made of one)."""
    if isinstance(net, (ResidualNet, OnnxResidual)):
        return net if isinstance(net, ResidualNet) else net.module
    raise TypeError(f"not a tier-1 net: {type(net).__name__}")


def weights_sha(net) -> str:
    """sha256 (first 16 hex digits) of a tier-1 net's weights: which net a diffusion model's tier-1 prior was made with
    (`x2video.train.cache`'s `prior_net`, the shipped `training.json`'s)."""
    h = hashlib.sha256()
    for k, v in sorted(torch_module(net).state_dict().items()):
        h.update(k.encode())
        h.update(v.detach().to("cpu", torch.float32).contiguous().numpy().tobytes())
    return h.hexdigest()[:16]


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
