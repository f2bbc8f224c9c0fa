"""What every attention processor here does around its own math, as diffusers' `AttnProcessor2_0` does it:
the token layout in and out (spatial norm, (B, C, H, W) -> (B, L, C), group norm; then back, residual
connection, output rescale), the attention mask per head, and the head reshapes; `TokenProcessor` is
the processor shape both of ours take."""
from __future__ import annotations

from typing import TYPE_CHECKING

import torch
from diffusers.models.attention_processor import Attention
from torch import nn

if TYPE_CHECKING:
    from x2video.model.context import AttnContext


def heads_split(x: torch.Tensor, heads: int) -> torch.Tensor:
    """(B, L, H*d) -> (B, H, L, d)"""
    b, n, c = x.shape
    return x.view(b, n, heads, c // heads).transpose(1, 2)


def heads_merge(x: torch.Tensor) -> torch.Tensor:
    """(B, H, L, d) -> (B, L, H*d)"""
    b, h, n, d = x.shape
    return x.transpose(1, 2).reshape(b, n, h * d)


def tokens_in(attn: Attention, hidden_states: torch.Tensor, temb: torch.Tensor | None) -> tuple[torch.Tensor, torch.Size | None]:
    """(x (B, L, C), the (B, C, H, W) shape to restore, or None when the input was already tokens)."""
    if attn.spatial_norm is not None:
        hidden_states = attn.spatial_norm(hidden_states, temb)
    shape = None
    if hidden_states.ndim == 4:
        shape = hidden_states.shape
        b, c, h, w = shape
        hidden_states = hidden_states.view(b, c, h * w).transpose(1, 2)  # (B, L, C)
    if attn.group_norm is not None:
        hidden_states = attn.group_norm(hidden_states.transpose(1, 2)).transpose(1, 2)
    return hidden_states, shape


def head_mask(attn: Attention, attention_mask: torch.Tensor | None, key_length: int, batch: int) -> torch.Tensor | None:
    """diffusers' attention mask as SDPA takes it, (B, H, 1 or Lq, Lk), or None."""
    if attention_mask is None:
        return None
    mask = attn.prepare_attention_mask(attention_mask, key_length, batch)
    return mask.view(batch, attn.heads, -1, mask.shape[-1])


def tokens_out(attn: Attention, out: torch.Tensor, residual: torch.Tensor, shape: torch.Size | None) -> torch.Tensor:
    """(B, L, C) back to the input's layout, plus the residual connection and the output rescale."""
    if shape is not None:
        out = out.transpose(-1, -2).reshape(shape)  # (B, C, H, W)
    if attn.residual_connection:
        out = out + residual
    return out / attn.rescale_output_factor


class TokenProcessor(nn.Module):
    """A diffusers attention processor whose math (`attend`) sees tokens: (B, L, C) in, (B, L, C_out) out, before
    the residual. diffusers calls processor(attn, hidden_states, encoder_hidden_states=..., attention_mask=...,
    **cross_attention_kwargs) and passes only the keywords this signature names: `x2v` is ours."""

    def __call__(  # type: ignore[override]
        self,
        attn: Attention,
        hidden_states: torch.Tensor,
        encoder_hidden_states: torch.Tensor | None = None,
        attention_mask: torch.Tensor | None = None,
        temb: torch.Tensor | None = None,
        x2v: AttnContext | None = None,
    ) -> torch.Tensor:
        residual = hidden_states
        x, shape = tokens_in(attn, hidden_states, temb)  # (B, L, C)
        return tokens_out(attn, self.attend(attn, x, encoder_hidden_states, attention_mask, x2v), residual, shape)

    def attend(self, attn: Attention, x: torch.Tensor, encoder_hidden_states: torch.Tensor | None,
               attention_mask: torch.Tensor | None, x2v: AttnContext | None) -> torch.Tensor:
        """(B, L, C) tokens -> (B, L, C_out), output projection and dropout included."""
        raise NotImplementedError
