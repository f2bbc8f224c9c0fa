"""Masked Cross-Attention (paper Sec. Masked Cross-Attention, eq. mask_crossattn): global prompt everywhere, local prompts inside their masks.

    MCAttn(f) = CAttn(f, T_g) + sum_p M^p * CAttn(f, T_l^p)

A diffusers processor for `attn2` of every transformer block. The global prompt arrives as
the UNet's `encoder_hidden_states`; local prompts and masks arrive in the shared
`AttnContext` (`cross_attention_kwargs={"x2v": ctx}`). Masks are area-resized to the layer's
token grid; all P local prompts go through one batched SDPA call. CAttn includes the output
projection: sum_p M_p (W a_p + b) = W (sum_p M_p a_p) + (sum_p M_p) b, computed in that form.
"""
from __future__ import annotations

import torch
import torch.nn.functional as F
from diffusers.models.attention_processor import Attention

from x2video.model.context import AttnContext
from x2video.model.processor_io import TokenProcessor, head_mask, heads_merge, heads_split


class MaskedCrossAttnProcessor(TokenProcessor):
    """`attn2` processor: global cross-attention plus mask-weighted local cross-attentions. No weights of its own."""

    def attend(self, attn: Attention, x: torch.Tensor, encoder_hidden_states: torch.Tensor | None,
               attention_mask: torch.Tensor | None, x2v: AttnContext | None) -> torch.Tensor:
        """(BN, Lq, C) -> (BN, Lq, C_out): MCAttn, output projection and dropout included."""
        text = x if encoder_hidden_states is None else encoder_hidden_states  # (BN, Lt, D)
        if encoder_hidden_states is not None and attn.norm_cross:
            text = attn.norm_encoder_hidden_states(text)
        mask = head_mask(attn, attention_mask, text.shape[1], x.shape[0])

        q = heads_split(attn.to_q(x), attn.heads)  # (BN, H, Lq, d)
        k = heads_split(attn.to_k(text), attn.heads)  # (BN, H, Lt, d)
        v = heads_split(attn.to_v(text), attn.heads)
        if attn.norm_q is not None:
            q = attn.norm_q(q)
        if attn.norm_k is not None:
            k = attn.norm_k(k)
        # CAttn(f, T_g)
        out = attn.to_out[0](heads_merge(F.scaled_dot_product_attention(q, k, v, attn_mask=mask)).to(x.dtype))

        if x2v is not None and x2v.text_local is not None and x2v.text_local.shape[1] > 0:
            out = out + self.local(attn, q, x2v)

        return attn.to_out[1](out)  # dropout

    @staticmethod
    def local(attn: Attention, q: torch.Tensor, ctx: AttnContext) -> torch.Tensor:
        """sum_p M^p * CAttn(f, T_l^p) for q (BN, H, Lq, d) -> (BN, Lq, C_out), one batched SDPA over prompts."""
        assert ctx.text_local is not None
        bn, h, lq, d = q.shape
        n = ctx.num_frames
        b = bn // n
        tl = ctx.text_local.to(q.dtype)  # (B, P, Lt, D)
        if tl.shape[0] != b:
            raise ValueError(f"text_local has {tl.shape[0]} windows but the batch holds {b} windows of {n} frames")
        p, lt = tl.shape[1], tl.shape[2]
        if attn.norm_cross:
            tl = attn.norm_encoder_hidden_states(tl.flatten(0, 1)).view(b, p, lt, -1)
        k = heads_split(attn.to_k(tl.flatten(0, 1)), h)  # (B*P, H, Lt, d)
        v = heads_split(attn.to_v(tl.flatten(0, 1)), h)
        if attn.norm_k is not None:
            k = attn.norm_k(k)
        k = k.view(b, 1, p, h, lt, d).expand(b, n, p, h, lt, d).reshape(bn * p, h, lt, d)  # (BN*P, H, Lt, d)
        v = v.view(b, 1, p, h, lt, d).expand(b, n, p, h, lt, d).reshape(bn * p, h, lt, d)
        qp = q[:, None].expand(bn, p, h, lq, d).reshape(bn * p, h, lq, d)  # (BN*P, H, Lq, d)
        a = F.scaled_dot_product_attention(qp, k, v)  # (BN*P, H, Lq, d)
        a = heads_merge(a).view(bn, p, lq, h * d)  # (BN, P, Lq, C')
        m = ctx.masks_at(lq).to(a.dtype)  # (BN, P, Lq)
        if m.shape[0] != bn:
            raise ValueError(f"local_masks have {m.shape[0]} frames but the batch has {bn}")
        weighted = torch.einsum("bpl,bplc->blc", m, a)  # (BN, Lq, C')
        proj = attn.to_out[0]
        out = F.linear(weighted, proj.weight)  # (BN, Lq, C_out)
        if proj.bias is not None:
            out = out + m.sum(1)[..., None] * proj.bias  # (BN, Lq, 1) * (C_out,)
        return out
