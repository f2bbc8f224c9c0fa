"""Training batches from the latent cache: channel dropout, A|M|R masking and local prompts ON LATENTS, frame windows.

Per sample (XRGB and the paper, Sec. Implementation): each intrinsic channel is dropped
with p = 0.5 (its latent channels are zeros, as `encode_frames` gives for a dropped
channel); the global prompt is the room's caption (sometimes ""); 0..5 random visible
objects get A|M|R masked out (albedo, roughness, metallic and shading latents multiplied
by 1 - area-downsampled mask, the union mask as an input channel) with their object
caption as local prompt. Video samples are windows of N frames in keyframe mode (stride
(N-1)^(k-1)) or interpolation mode at level k, with the start (and end) frame's rgb
latent as reference with some probability. All windows of one batch share mode, level,
window length and reference positions (one `run_unet` call).
"""
from __future__ import annotations

import functools
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import numpy as np
import torch

from x2video.channels import INTRINSIC, VAE_ENCODED
from x2video.model.config import LATENT_SCALE_KEYS
from x2video.model.vae import area_downsample
from x2video.train.cache import PRIOR_KEYS, load_split, load_text, prior_key, read_info
from x2video.train.config import AugmentConfig, WindowConfig
from x2video.train.loop import process_index

CHANNELS = INTRINSIC
AMR = ("albedo", "roughness", "metallic")


@dataclass
class Batch:
    """One training batch: B windows of n frames, window-major (BN = B*n)."""

    x0: torch.Tensor  # (BN, 4, h, w) scaled rgb latents (the target)
    cond: torch.Tensor  # (BN, C_cond, h, w) conditioning latents, `encode_frames` layout
    ref: torch.Tensor | None  # (BN, 4, h, w) reference latents at ref_positions, zeros elsewhere
    ref_positions: tuple[int, ...]
    mode: str
    level: int
    num_frames: int
    text_global: torch.Tensor  # (B, L, D)
    text_local: torch.Tensor | None  # (B, P, L, D)
    local_masks: torch.Tensor | None  # (BN, P, H, W)

    @property
    def windows(self) -> int:
        return self.x0.shape[0] // self.num_frames

    def to(self, device: torch.device | str) -> "Batch":
        mv = lambda x: None if x is None else x.to(device)  # noqa: E731
        return Batch(mv(self.x0), mv(self.cond), mv(self.ref), self.ref_positions, self.mode, self.level, self.num_frames,
                     mv(self.text_global), mv(self.text_local), mv(self.local_masks))


class LatentData:
    """One split of a latent cache in memory, scaled by the model's latent scales; draws batches."""

    def __init__(self, cache_dir: str | Path, split: str, latent_scales: dict[str, float], shading_prior: bool) -> None:
        self.info = read_info(cache_dir)
        t = load_split(cache_dir, split)
        self.shading_prior = shading_prior
        self.lat = {k: (t[k].float() * latent_scales[k]).half() for k in LATENT_SCALE_KEYS}
        #: what the prior latents hold (`ModelConfig.prior`): "shading" or "tier1", as the cache was built
        self.prior = self.info.prior
        if shading_prior:
            self.lat.update({k: (t[k].float() * latent_scales["rgb"]).half() for k in PRIOR_KEYS[self.prior]})
        self.irradiance = t["irradiance"]  # (F, 3, h, w) float16
        self.ids = t["ids"]  # (F, H, W) int16
        self.row_room = t["room"].long()
        self.text = load_text(cache_dir).float()  # (U, L, D)
        self.prompt_index = {p: i for i, p in enumerate(self.info.prompts)}
        self.rooms = [r for r in self.info.rooms if r["split"] == split]
        self.room_by_index = {i: r for i, r in enumerate(self.info.rooms)}
        if not self.rooms:
            raise ValueError(f"{cache_dir}: the {split} split holds no rooms")
        self.num_rows = int(self.ids.shape[0])
        self.latent_size = tuple(self.info.latent_size)

    @functools.cached_property
    def rgb_std(self) -> torch.Tensor:
        """(C,) standard deviation of each RGB latent channel over the split (the scale of `object_shift`;
        computed on first use, so runs without --ref-shift-p never pay for it)."""
        return self.lat["rgb"].float().std(dim=(0, 2, 3))

    # -- conditioning of given rows --------------------------------------------------
    def conditioning(self, rows: torch.Tensor, keep: dict[str, bool], amr_mask: torch.Tensor | None) -> torch.Tensor:
        """(n,) cache rows, kept channels, (n, 1, H, W) pixel A|M|R mask or None -> (n, C_cond, h, w) float32."""
        n = rows.shape[0]
        h, w = self.latent_size
        m = area_downsample(amr_mask, (h, w)) if amr_mask is not None else torch.zeros(n, 1, h, w)  # (n, 1, h, w)
        parts = []
        for name in VAE_ENCODED:
            z = self.lat[name][rows].float() if keep[name] else torch.zeros(n, 4, h, w)
            parts.append(z * (1 - m) if name in AMR else z)
        parts.append(self.irradiance[rows].float() if keep["irradiance"] else torch.zeros(n, 3, h, w))
        parts.append(m)
        if self.shading_prior:
            key = prior_key(self.prior, keep)
            if key is not None:
                parts.append(self.lat[key][rows].float() * (1 - m))
            else:
                parts.append(torch.zeros(n, 4, h, w))
        return torch.cat(parts, dim=1)  # (n, 20|24, h, w)

    def visible_objects(self, row: int, min_frac: float) -> list[int]:
        ids = self.ids[row]
        vals, counts = torch.unique(ids, return_counts=True)
        room = self.room_by_index[int(self.row_room[row])]
        return [int(v) for v, c in zip(vals, counts) if int(v) != 0 and str(int(v)) in room["objects"] and c >= min_frac * ids.numel()]

    # -- batches --------------------------------------------------------------------
    def sample(self, rng: np.random.Generator, windows: list[list[int]], aug: AugmentConfig, *, mode: str = "key", level: int = 1,
               ref_positions: tuple[int, ...] = ()) -> Batch:
        """A batch of the given windows (each a list of cache rows, all of equal length)."""
        n = len(windows[0])
        H, W = self.ids.shape[-2:]
        conds, masks_local, locals_idx, globals_idx = [], [], [], []
        for rows in windows:
            r = torch.as_tensor(rows, dtype=torch.long)
            keep = {c: bool(rng.random() >= aug.channel_drop_p) for c in CHANNELS}
            room = self.room_by_index[int(self.row_room[rows[0]])]
            objs: list[int] = []
            if aug.max_masks > 0 and rng.random() < aug.mask_p:
                cand = self.visible_objects(rows[0], aug.min_object_frac)
                if cand:
                    k = int(rng.integers(1, min(aug.max_masks, len(cand)) + 1))
                    objs = [int(o) for o in rng.choice(cand, size=k, replace=False)]
            ids = self.ids[r].long()  # (n, H, W)
            obj_masks = torch.stack([(ids == o).float() for o in objs], dim=1) if objs else torch.zeros(n, 0, H, W)  # (n, P, H, W)
            union = obj_masks.amax(dim=1, keepdim=True) if objs else None  # (n, 1, H, W)
            conds.append(self.conditioning(r, keep, union))
            with_text = [i for i, o in enumerate(objs) if rng.random() < aug.local_prompt_p]
            masks_local.append(obj_masks[:, with_text])
            locals_idx.append([self.prompt_index[room["objects"][str(objs[i])]] for i in with_text])
            caption = room["caption"] if rng.random() >= aug.prompt_drop_p else ""
            globals_idx.append(self.prompt_index[caption])
        all_rows = torch.as_tensor([r for rows in windows for r in rows], dtype=torch.long)
        x0 = self.lat["rgb"][all_rows].float()  # (BN, 4, h, w)
        ref = None
        if ref_positions and aug.ref_shift_p > 0:
            for b, rows in enumerate(windows):
                if rng.random() < aug.ref_shift_p:
                    std = float(rng.uniform(0.0, aug.ref_shift_std)) * self.rgb_std  # (C,)
                    x0[b * n : (b + 1) * n] += object_shift(self.ids[torch.as_tensor(rows, dtype=torch.long)], self.latent_size, std, rng)
        if ref_positions:
            ref = torch.zeros_like(x0).view(len(windows), n, *x0.shape[1:])  # (B, n, 4, h, w)
            ref[:, list(ref_positions)] = x0.view(len(windows), n, *x0.shape[1:])[:, list(ref_positions)]
            ref = ref.flatten(0, 1)  # (BN, 4, h, w)
        p = max(len(i) for i in locals_idx)
        text_local = local_masks = None
        if p > 0:
            L, D = self.text.shape[1:]
            text_local = torch.zeros(len(windows), p, L, D)  # (B, P, L, D); padded prompts have zero masks
            local_masks = torch.zeros(len(windows) * n, p, H, W)  # (BN, P, H, W)
            for b, (idx, m) in enumerate(zip(locals_idx, masks_local)):
                if idx:
                    text_local[b, : len(idx)] = self.text[idx]
                    local_masks[b * n : (b + 1) * n, : len(idx)] = m
        return Batch(x0, torch.cat(conds), ref, tuple(ref_positions), mode, level, n,
                     self.text[globals_idx], text_local, local_masks)

    def random_frames(self, rng: np.random.Generator, batch: int) -> list[list[int]]:
        """`batch` single-frame windows from random rows (image stage)."""
        starts = [self.rooms[i] for i in rng.integers(len(self.rooms), size=batch)]
        return [[r["start"] + int(rng.integers(r["num_frames"]))] for r in starts]

    def random_windows(self, rng: np.random.Generator, batch: int, wc: WindowConfig) -> tuple[list[list[int]], str, int, tuple[int, ...]]:
        """`batch` windows sharing mode, level, length and reference positions (video stage)."""
        longest = max(r["num_frames"] for r in self.rooms)
        mode = "interp" if rng.random() < wc.interp_p else "key"
        n = wc.frames
        if rng.random() < wc.short_p and wc.frames > (3 if mode == "interp" else 2):
            n = int(rng.integers(3 if mode == "interp" else 2, wc.frames))
        if n < 3 and mode == "interp":
            mode = "key"
        feasible = [k for k in range(1, wc.levels + 1) if (n - 1) * (wc.frames - 1) ** (k - 1) + 1 <= longest]
        if not feasible:  # rooms shorter than a window: the longest window they allow
            n = min(n, longest)
            feasible = [1]
            if n < 3:
                mode = "key"
        k = int(rng.choice(feasible))
        stride = (wc.frames - 1) ** (k - 1)
        span = (n - 1) * stride + 1
        rooms = [r for r in self.rooms if r["num_frames"] >= span]
        reverse = rng.random() < wc.reverse_p
        windows = []
        for i in rng.integers(len(rooms), size=batch):
            r = rooms[i]
            s = int(rng.integers(r["num_frames"] - span + 1))
            rows = [r["start"] + s + j * stride for j in range(n)]
            windows.append(rows[::-1] if reverse else rows)
        if mode == "interp":
            refs: tuple[int, ...] = (0, n - 1) if rng.random() < wc.ref_p_interp else ()
        else:
            refs = (0,) if rng.random() < wc.ref_p_key else ()
        return windows, mode, k if mode == "interp" else wc.levels, refs


def object_shift(ids: torch.Tensor, size: tuple[int, int], std: torch.Tensor, rng: np.random.Generator) -> torch.Tensor:
    """(n, C, h, w) latent offset of one window whose frames have object ids (n, H, W): one N(0, std^2)
    offset per latent channel (std: (C,), C the latent's channels) for the window and one per object id, each object's spread over its
    area-downsampled pixels. It follows the objects as the camera moves, as a generated keyframe's
    departures from the ground truth (a sofa a shade off, a warmer wall) follow them into the frames
    interpolated from it; training on targets shifted with their references was meant to teach the
    interpolation mode to carry such departures instead of falling back to what the channels say.
    Measured against a control fine-tune it made recursive sampling worse in PSNR and TC
    (docs/TRAINING.md), so `AugmentConfig.ref_shift_p` is off by default."""
    uniq = torch.unique(ids)  # (K,)
    onehot = (ids[:, None] == uniq[None, :, None, None]).float()  # (n, K, H, W)
    cover = area_downsample(onehot, size)  # (n, K, h, w)
    std = std.float()  # (C,)
    per_object = torch.from_numpy(rng.standard_normal((uniq.numel(), std.numel()))).float() * std  # (K, C)
    whole = torch.from_numpy(rng.standard_normal(std.numel())).float() * std  # (C,)
    return torch.einsum("nkhw,kc->nchw", cover, per_object) + whole[None, :, None, None]  # (n, C, h, w)


class _Draws(torch.utils.data.IterableDataset):
    """Endless batches from `draw(rng)`, in the training process or in DataLoader workers (each
    worker adds its id to the seed)."""

    def __init__(self, draw, seed: list[int]) -> None:
        self.draw, self.seed = draw, seed

    def __iter__(self) -> Iterator[Batch]:
        info = torch.utils.data.get_worker_info()  # None in the training process itself
        rng = np.random.default_rng(self.seed if info is None else [*self.seed, info.id])
        while True:
            yield self.draw(rng)


def _as_is(b: Batch) -> Batch:
    return b


def _one_thread(_: int) -> None:
    torch.set_num_threads(1)  # the workers' small tensor ops; many workers share the cores


def _stream(draw, seed: int, workers: int):
    """`make(start)` for `train`: batches drawn here (workers=0, reproducible as before) or by
    `workers` forked processes prefetching ahead of the optimiser (a GPU step outruns one CPU
    drawing them). Every worker seeds from (seed, start step, process rank, worker id)."""

    def make(start: int) -> Iterator[Batch]:
        draws = _Draws(draw, [seed, start, process_index()])
        if workers <= 0:
            return iter(draws)
        return iter(torch.utils.data.DataLoader(draws, batch_size=None, num_workers=workers, collate_fn=_as_is,
                                                worker_init_fn=_one_thread, prefetch_factor=4, multiprocessing_context="fork"))

    return make


def image_batches(data: LatentData, batch: int, aug: AugmentConfig, seed: int, workers: int = 0):
    """Batch source for `train`: single frames, no reference (the XRGB-style image stage)."""
    return _stream(lambda rng: data.sample(rng, data.random_frames(rng, batch), aug), seed, workers)


def video_batches(data: LatentData, batch: int, aug: AugmentConfig, wc: WindowConfig, seed: int, workers: int = 0):
    """Batch source for `train`: keyframe / interpolation windows with optional references."""

    def draw(rng: np.random.Generator) -> Batch:
        windows, mode, level, refs = data.random_windows(rng, batch, wc)
        return data.sample(rng, windows, aug, mode=mode, level=level, ref_positions=refs)

    return _stream(draw, seed, workers)
