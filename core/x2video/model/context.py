"""The per-call context both attention processors read (`cross_attention_kwargs={"x2v": ctx}`).

diffusers passes `cross_attention_kwargs` to `attn1` and `attn2` of every transformer block
and drops keywords a processor does not name, so Hybrid Self-Attention and Masked
Cross-Attention share this one object: window size, reference positions, adapter mode and
level (paper Sec. Adaptation to Recursive Sampling), local prompts and their masks.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import torch
import torch.nn.functional as F

MODES = ("key", "interp", "seq")


@dataclass
class AttnContext:
    """What one UNet call over B windows of N frames (batch B*N, window-major) needs to know."""

    num_frames: int
    """N: frames per window; the UNet batch is B*N with the frames of a window adjacent."""
    latent_size: tuple[int, int]
    """(h, w) of the UNet input latents; each attention layer's token grid is derived from it."""
    ref_positions: tuple[int, ...] = ()
    """Window positions that hold references: () none, (0,) keyframe mode, (0, N-1) interpolation."""
    mode: str = "key"
    """'key' (keyframe prediction), 'interp' (interpolation) or 'seq' (sequential baseline: keyframe adapters)."""
    level: int = 1
    """Recursive level k >= 1 of an interpolation window (selects the temporal LoRA branch)."""
    text_local: torch.Tensor | None = None
    """(B, P, L, D) local prompt token embeddings (P may be 0), or None."""
    local_masks: torch.Tensor | None = None
    """(B*N, P, H, W) masks of the local prompts in [0, 1], any resolution (area-resized per layer)."""
    _masks: dict[int, torch.Tensor] = field(default_factory=dict, repr=False)

    def __post_init__(self) -> None:
        if self.mode not in MODES:
            raise ValueError(f"AttnContext.mode must be one of {MODES}, got {self.mode!r}")
        if self.num_frames < 1:
            raise ValueError(f"AttnContext.num_frames must be >= 1, got {self.num_frames}")
        for p in self.ref_positions:
            if not 0 <= p < self.num_frames:
                raise ValueError(f"reference position {p} outside window of {self.num_frames} frames")
        if self.mode == "interp" and len(self.ref_positions) not in (0, 2):
            raise ValueError(f"interpolation mode needs two reference positions, got {self.ref_positions}")
        if (self.text_local is None) != (self.local_masks is None):
            raise ValueError("AttnContext: text_local and local_masks go together")
        if self.text_local is not None and self.local_masks is not None:
            if self.text_local.shape[1] != self.local_masks.shape[1]:
                raise ValueError(
                    f"{self.text_local.shape[1]} local prompts but {self.local_masks.shape[1]} local masks"
                )

    # -- Hybrid Self-Attention -------------------------------------------------
    @property
    def interpolating(self) -> bool:
        return self.mode == "interp"

    def source_positions(self) -> tuple[int, ...]:
        """Window positions the Reference Attention reads: start (and end when interpolating)."""
        if self.interpolating:
            return self.ref_positions if self.ref_positions else (0, self.num_frames - 1)
        return self.ref_positions[:1] if self.ref_positions else (0,)

    def temporal_branch(self, interp_levels: int) -> str:
        """Name of the temporal LoRA branch: 'key', or 'interp<k>' with k clamped to interp_levels."""
        if not self.interpolating:
            return "key"
        return f"interp{min(max(self.level, 1), interp_levels)}"

    # -- Masked Cross-Attention ------------------------------------------------
    def grid(self, seq_len: int) -> tuple[int, int]:
        """Token grid (gh, gw) of an attention layer with seq_len tokens (stride-2 convs: ceil halving)."""
        h, w = self.latent_size
        while h * w > seq_len:
            h, w = math.ceil(h / 2), math.ceil(w / 2)
        if h * w != seq_len:
            raise ValueError(f"cannot match {seq_len} tokens to a grid of latent size {self.latent_size}")
        return h, w

    def masks_at(self, seq_len: int) -> torch.Tensor:
        """(B*N, P, seq_len) local masks area-resized to a layer's token grid (cached per grid)."""
        assert self.local_masks is not None
        if seq_len not in self._masks:
            gh, gw = self.grid(seq_len)
            m = self.local_masks.float()  # (BN, P, H, W)
            if m.shape[1] == 0:
                r = m.new_zeros(m.shape[0], 0, gh * gw)
            else:
                r = F.adaptive_avg_pool2d(m, (gh, gw)).flatten(2)  # (BN, P, gh*gw)
            self._masks[seq_len] = r
        return self._masks[seq_len]
