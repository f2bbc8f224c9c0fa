"""Training settings without the training code (no torch): the optimisation loop, conditioning augmentation
and video windows. Field docstrings are the help of `x2video train`'s flags (`x2video.cli.fields`)."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Literal


@dataclass
class LoopConfig:
    """Optimisation settings shared by every stage (field docstrings are CLI help)."""

    steps: int = 1000
    """Total optimiser steps (a resumed run continues up to this number)."""
    lr: float = 1e-4
    """Peak AdamW learning rate (after linear warm-up)."""
    warmup: int = 50
    """Linear warm-up steps."""
    lr_half_every: int = 0
    """Halve the learning rate every this many steps (paper: 20,000); 0 = constant."""
    weight_decay: float = 0.0
    grad_clip: float = 1.0
    ema_decay: float = 0.999
    """EMA decay of the weights that get saved for inference; 0 disables EMA."""
    ckpt_every: int = 500
    """Write a resumable `step-XXXXXXXXX/` checkpoint every this many steps (and at the end)."""
    keep_ckpts: int = 2
    """How many step checkpoints to keep on disk."""
    time_limit_s: float = 0.0
    """Stop (with a checkpoint) after this many seconds of training; 0 = no limit."""
    seed: int = 0
    """Seed of the weights' initialisation and of the batches drawn."""
    mixed_precision: Literal["no", "fp16", "bf16"] = "no"
    """accelerate mixed precision (GPU)."""
    workers: int = 0
    """Processes drawing batches ahead of the optimiser (0: drawn in the training process). Not
    part of what a run is: a run resumes with any number, with fresh batches either way."""


@dataclass
class AugmentConfig:
    """Conditioning augmentation (field docstrings are CLI help)."""

    channel_drop_p: float = 0.5
    """Probability of dropping each intrinsic channel (XRGB / paper: 0.5)."""
    prompt_drop_p: float = 0.3
    """Probability the global prompt is "" instead of the room's caption."""
    mask_p: float = 0.5
    """Probability a sample has A|M|R-masked objects (then 1..max_masks of them)."""
    max_masks: int = 5
    """Most masked objects (local prompts) per sample."""
    local_prompt_p: float = 0.8
    """Probability a masked object carries its caption as a local prompt."""
    min_object_frac: float = 0.01
    """Objects covering less of the first frame than this are not picked for masks."""
    ref_shift_p: float = 0.0
    """Probability a window with references has its target and its references shifted alike by a random
    latent offset per object (and one for the whole window), so that what the references show beyond
    the channels is what the other frames must show too (`object_shift`); 0: off. Windows without
    references are never shifted."""
    ref_shift_std: float = 0.3
    """Largest standard deviation of those offsets, as a fraction of each RGB latent channel's standard
    deviation over the split (each window draws its own fraction in [0, this])."""


@dataclass
class WindowConfig:
    """How video windows are drawn (paper Sec. Recursive Sampling / Implementation: N=5, K=3)."""

    frames: int = 5
    """N: frames per window."""
    levels: int = 3
    """K: keyframe windows use stride (N-1)^(k-1) for k in 1..K; interpolation levels 1..K."""
    interp_p: float = 0.5
    """Probability a batch is interpolation-mode windows (else keyframe-mode)."""
    ref_p_key: float = 0.5
    """Probability keyframe windows carry the start frame as reference."""
    ref_p_interp: float = 0.5
    """Probability interpolation windows carry the start and end frames as references."""
    reverse_p: float = 0.5
    """Probability the windows run backwards in time (the planner's backward keyframe windows)."""
    short_p: float = 0.1
    """Probability of a shorter window (the planner's tail windows), 2..N-1 frames (3.. interpolating)."""
