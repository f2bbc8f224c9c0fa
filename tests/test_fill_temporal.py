"""The classical fill over time: frames between keyframes must not flicker more than the path trace they stand in for.

A Cycles albedo pass is a few-sample estimate, noisy differently on every frame, while the denoised rgb is smooth:
the fill's albedo (`stable_albedo`) averages that noise out over frames and keeps the texture on the surface."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
from test_base_fill import H, W, psnr, wall_shot

from x2video.base.fill import FillConfig, fill_frame, stable_albedo, warp_by_depth
from x2video.base.keyframes import only_keyframes
from x2video.shot import ArrayShot

XS = [0.0, 0.1, 0.2, 0.3, 0.4]


def noisy_albedo(shot: ArrayShot, sigma: float = 0.05, seed: int = 0) -> ArrayShot:
    """`shot` with noise drawn anew on every frame added to its albedo pass (its rgb stays clean, as denoised)."""
    rng = np.random.default_rng(seed)
    arrays = {k: np.stack([shot.channel(k, t) for t in range(shot.num_frames)]) for k in ("albedo", "normal", "depth", "rgb")}
    arrays["albedo"] = np.clip(arrays["albedo"] + rng.normal(0, sigma, arrays["albedo"].shape), 0.05, 1).astype(np.float32)
    return ArrayShot(arrays, poses=shot.info.poses)


def warp_error(shot: ArrayShot, frames: dict[int, np.ndarray]) -> float:
    """Mean |frame t - frame t+1 reprojected onto t| over consecutive frames (the flow-warping error of TC)."""
    errs = []
    for t in sorted(frames)[:-1]:
        back, ok = warp_by_depth(shot, t, t + 1, frames[t + 1], FillConfig())
        errs.append(np.abs(frames[t] - back)[ok].mean())
    return float(np.mean(errs))


def test_stable_albedo_averages_per_frame_noise_and_keeps_the_texture():
    clean = wall_shot(XS)
    noisy = noisy_albedo(clean)
    own = noisy.channel("albedo", 2)
    stable = stable_albedo(noisy, 2, FillConfig())
    truth = clean.channel("albedo", 2)
    inner = (slice(4, H - 4), slice(8, W - 8))  # pixels every neighbour sees
    assert np.abs(stable - truth)[inner].mean() < 0.5 * np.abs(own - truth)[inner].mean()
    # the wall's texture itself (a sine of its world position) survives: noise-free albedo comes back as it is
    np.testing.assert_allclose(stable_albedo(clean, 2, FillConfig())[inner], truth[inner], atol=0.01)
    # the setting is what does it: with no frames either side the albedo pass is taken as it is
    np.testing.assert_array_equal(stable_albedo(noisy, 2, FillConfig(albedo_frames=0)), own)


def test_frames_between_flicker_less_with_stable_albedo():
    clean = wall_shot(XS)
    shot = only_keyframes(noisy_albedo(clean), "every:4")
    for_time = {}
    for cfg in (FillConfig(), replace(FillConfig(), albedo_frames=0)):
        frames = {t: fill_frame(shot, t, cfg).rgb for t in (1, 2, 3)}
        for_time[cfg.albedo_frames] = (warp_error(clean, frames), min(psnr(frames[t], clean.channel("rgb", t)) for t in frames))
    (stable_err, stable_psnr), (raw_err, raw_psnr) = for_time[FillConfig().albedo_frames], for_time[0]
    assert stable_err < 0.6 * raw_err
    assert stable_psnr > raw_psnr + 2


class CountingShot(ArrayShot):
    """An ArrayShot that counts its reads per (channel, frame)."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.reads: dict[tuple[str, int], int] = {}

    def _read(self, name: str, t: int) -> np.ndarray:
        self.reads[name, t] = self.reads.get((name, t), 0) + 1
        return super()._read(name, t)


def test_a_shot_filled_in_order_reads_each_frame_once_and_keeps_only_the_frames_in_reach():
    xs = [0.02 * i for i in range(9)]
    full = wall_shot(xs)
    arrays = {k: np.stack([full.channel(k, t) for t in range(9)]) for k in ("albedo", "normal", "depth", "rgb")}
    shot = only_keyframes(CountingShot(arrays, poses=full.info.poses), "0,8")
    counting = shot.base_shot
    cache: dict = {}
    reach = FillConfig().albedo_frames
    for t in range(1, 8):
        fill_frame(shot, t, shading=cache)
        assert cache["frames"].frames() <= {*range(t - reach, t + reach + 2), 0, 8}
    reads = {(name, t): n for (name, t), n in counting.reads.items() if name in ("albedo", "depth", "normal")}
    # once in order; the frames next to keyframe 8 once more, read early for its own (stable) albedo
    assert all(n == 1 for (_, t), n in reads.items() if t < 8 - reach) and max(reads.values()) == 2
