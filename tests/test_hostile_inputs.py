"""Tiers 0 and 1 on hostile channel values (found by bench/stability.py): every channel dropped, NaN/Inf inputs."""
from __future__ import annotations

import numpy as np
from test_tiers import full_shot, render, with_net

from x2video.edits import Edits
from x2video.formula import formula
from x2video.model import residual as R
from x2video.render.settings import RenderSettings
from x2video.shot import ArrayShot


def test_formula_and_features_with_every_channel_dropped():
    ch = {n: None for n in ("albedo", "normal", "roughness", "metallic", "irradiance")}
    assert formula(ch, (5, 7)).shape == (5, 7, 3)
    x, f = R.features(ch, (5, 7))
    assert x.shape[1:] == (5, 7) and not f.any()


def test_formula_tier_renders_a_shot_with_every_channel_dropped():
    shot = full_shot(2, 8, 8)
    edits = Edits()
    edits.dropped = {"albedo", "normal", "roughness", "metallic", "irradiance"}
    _, frames = render(with_net(), shot, RenderSettings(quality="formula"), edits)
    assert len(frames) == 2 and all(not f.any() for f in frames.values())


def test_nonfinite_inputs_give_finite_frames_in_tiers_0_and_1():
    base = full_shot(2, 16, 24)
    arrays = {n: np.stack([base.channel(n, t) for t in range(2)]) for n in base.channels}
    arrays["irradiance"][:, 2:6, 3:9] = np.nan
    arrays["irradiance"][:, 8:10, 3:9] = np.inf
    arrays["irradiance"][:, 10:12, 3:9] = -np.inf
    arrays["albedo"][:, 12:14, :4] = np.nan
    shot = ArrayShot(arrays)
    x, f = R.features(shot.frame(0))
    assert np.isfinite(x).all() and np.isfinite(f).all()
    assert (f[:, 2:6, 3:9] == 0).all()  # non-finite irradiance counts as 0, as the loaders make it
    for quality in ("formula", "residual"):
        _, frames = render(with_net(), shot, RenderSettings(quality=quality))
        assert all(np.isfinite(fr).all() for fr in frames.values()), quality


def test_diffusion_tier_treats_nonfinite_channels_as_zero():
    """The sampler's conditioning used to raise on NaN/Inf; it now zeroes them with a warning, as the loaders do."""
    import pytest

    from x2video.model.pipeline import X2VideoModel

    base = full_shot(1, 16, 16)
    arrays = {n: np.stack([base.channel(n, 0)]) for n in base.channels}
    arrays["irradiance"][:, 2:6, 3:9] = np.nan
    arrays["albedo"][:, 8:10, 3:9] = np.inf
    with pytest.warns(RuntimeWarning, match="NaN/Inf"):
        _, frames = render(X2VideoModel.untrained("tiny", seed=0), ArrayShot(arrays), RenderSettings(quality="diffusion", steps=1))
    assert len(frames) == 1 and np.isfinite(frames[0]).all()


def test_classical_shading_counts_nonfinite_values_as_zero():
    from x2video.model.shading import classical_shading

    shot = full_shot(1, 8, 8)
    ch = dict(shot.frame(0))
    ch["albedo"] = ch["albedo"].copy()
    ch["irradiance"] = ch["irradiance"].copy()
    ch["albedo"][0, :4] = np.nan
    ch["irradiance"][1, :4] = np.inf
    out = classical_shading(ch)
    assert np.isfinite(out).all() and (out[1, :4] == 0).all()
