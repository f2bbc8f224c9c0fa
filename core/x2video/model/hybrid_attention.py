"""Hybrid Self-Attention (paper Sec. Hybrid Self-Attention): Self + Reference + Multi-Head Full temporal, alpha-blended.

    HybridAttn(f^i) = (1 - a_r - a_t) SelfAttn(f^i) + a_r RefAttn(f^i) + a_t TempAttn(f^i)      (alpha blender)
    RefAttn(f^i)    = a_r0 Attn(w_r0^q f^i, w_r0^k f^0, w_r0^v f^0)
                    + a_r1 Attn(w_r1^q f^i, w_r1^k f^{N-1}, w_r1^v f^{N-1})                  (eq. refattn_lora)
    TempAttn(f^i)   = Attn(Q_t^{i,h}, K_t^{i_t,h}, V_t^{i_t,h}),  i_t = (i + h) mod N           (MHF temporal)

A diffusers attention processor for `attn1` of every transformer block. The module
(`Attention`) keeps owning the self-attention weights `to_q/to_k/to_v/to_out`; this
processor owns the reference and temporal projections (copied from `to_q/to_k/to_v` at
conversion), their switchable LoRA branches and the per-layer scalars a_r, a_t (zero at
conversion, so the video UNet equals the image UNet). The three branches are blended
before the shared output projection `to_out`: since the blend weights sum to one,
`to_out(sum_i w_i a_i) == sum_i w_i to_out(a_i)` exactly, bias included.
"""
from __future__ import annotations

import torch
import torch.nn.functional as F
from diffusers.models.attention_processor import Attention
from torch import nn

from x2video.model.config import HybridConfig
from x2video.model.context import AttnContext
from x2video.model.lora import SwitchableQKV
from x2video.model.processor_io import TokenProcessor, head_mask, heads_merge, heads_split

REF_BRANCHES = ("r0", "r1")


def temporal_branches(interp_levels: int) -> tuple[str, ...]:
    """LoRA branch names of MHF temporal attention: keyframe mode, then one per interpolation level."""
    return ("key",) + tuple(f"interp{k}" for k in range(1, interp_levels + 1))


def mhf_gather(kv: torch.Tensor, num_frames: int, heads: int) -> torch.Tensor:
    """Route head h of frame i to frame (i + h) mod N: projected keys or values (B*N, L, H*d) -> (B*N, H, L, d).

    Frames are tiled to N+H-1 (so frame i+h needs no modulo), a sliding window of N frames is
    taken per start frame, and the (window, head) diagonal picks window h for head h: all
    views, then one copy into the attention layout. The attention that follows costs exactly
    one self-attention (each query still sees L keys)."""
    bn, length, c = kv.shape
    b, n, d = bn // num_frames, num_frames, c // heads
    src = kv.view(b, n, length, heads, d)  # (B, N, L, H, d)
    if torch.onnx.is_in_onnx_export():  # ONNX has no Unfold of a traced size: one frame gather per head instead
        order = torch.arange(n, device=kv.device)
        per_head = [src[:, (order + h) % n, :, h] for h in range(heads)]  # H x (B, N, L, d): frame i + h, head h
        return torch.stack(per_head, dim=2).reshape(bn, heads, length, d)  # (B*N, H, L, d)
    total = n + heads - 1
    parts = [src] * (total // n) + ([src[:, : total % n]] if total % n else [])
    tiled = torch.cat(parts, dim=1) if len(parts) > 1 else src  # (B, N+H-1, L, H, d): frame j holds j mod N
    windows = tiled.unfold(1, n, 1)  # (B, H, L, H, d, N): [b, w, l, h, e, i] = frame w + i
    diag = torch.diagonal(windows, dim1=1, dim2=3)  # (B, L, d, N, H): [b, l, e, i, h] = frame i + h, head h
    return diag.permute(0, 3, 4, 1, 2).reshape(bn, heads, length, d)  # (B*N, H, L, d)


class HybridSelfAttnProcessor(TokenProcessor):
    """`attn1` processor: Self + Reference + MHF temporal attention with switchable LoRA (see module doc)."""

    def __init__(self, attn: Attention, hybrid: HybridConfig) -> None:
        super().__init__()
        self.interp_levels = hybrid.interp_levels
        self.ref = SwitchableQKV(attn.to_q, attn.to_k, attn.to_v, REF_BRANCHES, hybrid.lora_rank, hybrid.lora_alpha)
        self.temp = SwitchableQKV(
            attn.to_q, attn.to_k, attn.to_v, temporal_branches(hybrid.interp_levels), hybrid.lora_rank, hybrid.lora_alpha
        )
        p = attn.to_q.weight
        self.alpha_r = nn.Parameter(torch.zeros((), device=p.device, dtype=p.dtype))
        self.alpha_t = nn.Parameter(torch.zeros((), device=p.device, dtype=p.dtype))

    def attend(self, attn: Attention, x: torch.Tensor, encoder_hidden_states: torch.Tensor | None,
               attention_mask: torch.Tensor | None, x2v: AttnContext | None) -> torch.Tensor:
        """(BN, L, C) -> (BN, L, C_out): the blend of the three attentions, output projection included."""
        if encoder_hidden_states is not None:
            raise ValueError("HybridSelfAttnProcessor is a self-attention processor (attn1); got encoder_hidden_states")
        mask = head_mask(attn, attention_mask, x.shape[1], x.shape[0])

        # 1. SelfAttn(f^i): the pretrained path, unchanged.
        out = self._attend(attn, attn.to_q(x), attn.to_k(x), attn.to_v(x), mask)  # (BN, H, L, d)

        if x2v is not None:
            use_ref = self._active(self.alpha_r)
            use_temp = self._active(self.alpha_t) and x2v.num_frames > 1
            if use_ref or use_temp:
                blended = out * (1 - self.alpha_r - self.alpha_t)
                if use_ref:
                    blended = blended + self.alpha_r * self.reference(attn, x, x2v)
                if use_temp:
                    blended = blended + self.alpha_t * self.temporal(attn, x, x2v)
                out = blended

        out = heads_merge(out).to(x.dtype)  # (BN, L, H*d)
        return attn.to_out[1](attn.to_out[0](out))

    # -- branches ----------------------------------------------------------------
    def reference(self, attn: Attention, x: torch.Tensor, ctx: AttnContext) -> torch.Tensor:
        """RefAttn (eq. refattn_lora): (BN, L, C) -> (BN, H, L, d). Keyframe: r0 on the start
        frame with weight 1; interpolation: r0 on the start and r1 on the end frame, 0.5 each."""
        n = ctx.num_frames
        bn, length, c = x.shape
        frames = x.view(bn // n, n, length, c)  # (B, N, L, C)
        positions = ctx.source_positions()
        weights = (0.5, 0.5) if ctx.interpolating else (1.0,)
        out: torch.Tensor | None = None
        for branch, pos, w in zip(REF_BRANCHES, positions, weights):
            q = self.ref.q(x, branch)  # (BN, L, C')
            src = frames[:, pos]  # (B, L, C)
            k = self.ref.k(src, branch).repeat_interleave(n, dim=0)  # (BN, L, C')
            v = self.ref.v(src, branch).repeat_interleave(n, dim=0)  # (BN, L, C')
            o = self._attend(attn, q, k, v, None) * w  # (BN, H, L, d)
            out = o if out is None else out + o
        assert out is not None
        return out

    def temporal(self, attn: Attention, x: torch.Tensor, ctx: AttnContext) -> torch.Tensor:
        """MHF TempAttn: head h of frame i attends frame (i + h) mod N. (BN, L, C) -> (BN, H, L, d)."""
        branch = ctx.temporal_branch(self.interp_levels)
        q = heads_split(self.temp.q(x, branch), attn.heads)  # (BN, H, L, d)
        k = mhf_gather(self.temp.k(x, branch), ctx.num_frames, attn.heads)  # (BN, H, L, d), head h from frame (i+h) mod N
        v = mhf_gather(self.temp.v(x, branch), ctx.num_frames, attn.heads)
        if attn.norm_q is not None:
            q = attn.norm_q(q)
        if attn.norm_k is not None:
            k = attn.norm_k(k)  # per-head norm: commutes with the frame routing
        return F.scaled_dot_product_attention(q, k, v)

    # -- helpers -------------------------------------------------------------------
    @staticmethod
    def _attend(attn: Attention, q: torch.Tensor, k: torch.Tensor, v: torch.Tensor, mask: torch.Tensor | None) -> torch.Tensor:
        """Multi-head SDPA of projected (B, L, C') tensors -> (B, H, L, d)."""
        q, k, v = (heads_split(t, attn.heads) for t in (q, k, v))
        if attn.norm_q is not None:
            q = attn.norm_q(q)
        if attn.norm_k is not None:
            k = attn.norm_k(k)
        return F.scaled_dot_product_attention(q, k, v, attn_mask=mask)

    @staticmethod
    def _active(alpha: torch.Tensor) -> bool:
        """A branch is computed when its alpha is non-zero or gradients may flow to it (training)."""
        return torch.is_grad_enabled() and alpha.requires_grad or bool(alpha.detach() != 0)
