"""`x2video.model.plausible`: tier 1's correction of the formula judged per tile, the formula where it is implausible."""
from __future__ import annotations

import numpy as np
import pytest

from x2video.model import plausible as P


def _formula(h=96, w=128, seed=0):
    rng = np.random.default_rng(seed)
    return (0.2 + 0.6 * rng.random((h, w, 3))).astype(np.float32)


@pytest.mark.parametrize("size", [(1, 1), (5, 7), (96, 128), (224, 320), (1080, 1920), (1024, 1024), (3, 200)])
def test_tile_edges_cover_the_frame_with_about_square_tiles(size):
    ys, xs = P.tile_edges(size)
    assert ys[0] == 0 and ys[-1] == size[0] and xs[0] == 0 and xs[-1] == size[1]
    assert (np.diff(ys) >= 1).all() and (np.diff(xs) >= 1).all()
    assert max(len(ys), len(xs)) - 1 == min(P.GRID, max(size))


def test_tier1_equal_to_the_formula_passes_untouched():
    f = _formula()
    out, v = P.guard(f.copy(), f)
    assert not v.engaged and v.formula_share == 0
    np.testing.assert_array_equal(out, f)


def test_a_modest_correction_everywhere_passes():
    f = _formula()
    r = f * np.float32(np.exp(0.8 * P.FRAME_BOUND))
    out, v = P.guard(r, f)
    assert not v.engaged
    np.testing.assert_array_equal(out, r)


def test_a_frame_lifted_beyond_the_frame_bound_keeps_the_formula_everywhere():
    """The kitchen: tier 1 at 2.7x the formula over the frame."""
    f = _formula()
    out, v = P.guard(f * 2.7, f)
    assert v.rejected.all() and v.formula_share == 1.0
    np.testing.assert_array_equal(out, f)


def test_one_implausible_tile_keeps_the_formula_there_and_fades_into_its_neighbours():
    f = _formula(96, 128)
    ys, xs = P.tile_edges(f.shape[:2])
    r = f.copy()
    r[ys[2]:ys[3], xs[4]:xs[5]] *= 6.0  # one tile 6x the formula: below the frame bound over the whole frame
    out, v = P.guard(r, f)
    assert v.rejected.sum() == 1 and v.rejected[2, 4]
    np.testing.assert_array_equal(out[ys[2]:ys[3], xs[4]:xs[5]], f[ys[2]:ys[3], xs[4]:xs[5]])
    far = (slice(ys[5], None), slice(0, xs[2]))
    np.testing.assert_array_equal(out[far], r[far])
    w = P.plausible_weight(v.rejected, f.shape[:2])
    assert w.min() == 0 and w.max() == 1
    assert np.abs(np.diff(w, axis=0)).max() <= 0.2 and np.abs(np.diff(w, axis=1)).max() <= 0.2  # a ramp, not a step


def test_a_darkening_tile_is_judged_as_a_brightening_one():
    f = _formula(96, 128)
    ys, xs = P.tile_edges(f.shape[:2])
    r = f.copy()
    r[ys[0]:ys[1], xs[0]:xs[1]] /= 12.0
    _, v = P.guard(r, f)
    assert v.rejected[0, 0] and v.rejected.sum() == 1


def test_light_added_where_the_formula_is_black_counts_against_the_frames_light():
    """A lamp shade's tile: the formula black, tier 1 adds a glow. Small against the frame's light, it passes; the floor
    (FLOOR x the frame's mean) keeps a dark tile's ratio from exploding."""
    f = _formula(96, 128)
    ys, xs = P.tile_edges(f.shape[:2])
    f[ys[0]:ys[1], xs[0]:xs[1]] = 0
    r = f.copy()
    level = float(P.luminance(f).mean())
    r[ys[0]:ys[1], xs[0]:xs[1]] = 0.05 * level
    _, v = P.guard(r, f)
    assert not v.engaged
    r[ys[0]:ys[1], xs[0]:xs[1]] = 5.0 * level  # five times the frame's light on a black tile: implausible
    _, v = P.guard(r, f)
    assert v.rejected[0, 0]


def test_black_frames_and_nonfinite_values_do_not_break_the_judge():
    z = np.zeros((16, 16, 3), np.float32)
    out, v = P.guard(z, z)
    assert not v.engaged and np.isfinite(v.frame_log_ratio)
    f = _formula(16, 16)
    r = f.copy()
    r[0, 0] = np.nan
    _, v = P.guard(r, f)
    assert np.isfinite(v.tile_log_ratios).all()


def test_the_verdict_says_what_it_did():
    f = _formula()
    _, v = P.guard(f * 4, f)
    text = v.describe()
    assert f"{(4 + P.FLOOR) / (1 + P.FLOOR):.2f}x the formula" in text and f"{v.rejected.size} of {v.rejected.size} tiles" in text


def test_channels_outside_their_range_are_named_and_in_range_ones_pass():
    h, w = 40, 50
    ok = {"roughness": np.full((h, w, 1), 0.5, np.float32), "metallic": np.zeros((h, w, 1), np.float32)}
    assert P.out_of_range(ok) is None
    edges = dict(ok, roughness=ok["roughness"].copy())
    edges["roughness"][:, :1] = 1.0039  # an 8-bit map's rounding, and a column of filtered edge beyond it
    edges["roughness"][:1, :] = -0.3  # 2 % of the pixels: more than RANGE_SHARE
    assert "roughness" in (P.out_of_range(edges) or "")
    edges["roughness"][:1, :] = 0.0
    assert P.out_of_range(edges) is None  # the rounding alone is within RANGE_SLACK
    why = P.out_of_range(dict(ok, roughness=np.full((h, w, 1), -0.5, np.float32)))
    assert why is not None and "roughness" in why and "100%" in why and "-0.5" in why
    assert "metallic" in (P.out_of_range(dict(ok, metallic=np.full((h, w, 1), 255.0, np.float32))) or "")
    assert "metallic" in (P.out_of_range(dict(ok, metallic=np.full((h, w, 1), np.nan, np.float32))) or "")
    assert P.out_of_range({}) is None  # no such channel: nothing to judge


def test_irradiance_at_another_level_or_clipped_at_a_files_ceiling_is_named():
    rng = np.random.default_rng(1)
    irr = rng.uniform(0.1, 0.9, (40, 50, 3)).astype(np.float32)  # mean luminance 0.5: a level tier 1 knows
    assert P.out_of_range({"irradiance": irr}) is None
    assert "level" in (P.out_of_range({"irradiance": irr * 0.1}) or "")  # another renderer's scale, left as written
    assert "level" in (P.out_of_range({"irradiance": irr * 10}) or "")
    clipped = np.minimum(irr * 2.5, 1.0)  # an 8-bit file of a brighter scale: over a quarter of the pixels at 1
    assert "clipped" in (P.out_of_range({"irradiance": clipped}) or "")
    window = irr.copy()
    window[:5] = 1.0  # a window at the file's ceiling: 10 % of the frame
    assert P.out_of_range({"irradiance": window}) is None
    assert P.out_of_range({"irradiance": np.ones((40, 50, 3), np.float32)}) is None  # uniform light: nothing to tell
    assert P.out_of_range({"irradiance": np.minimum(irr * 2.5, 1.3)}) is None  # a ceiling that is not a file's 1.0


def test_a_frame_under_the_trusted_size_is_named():
    irr = np.full((16, 16, 3), 0.5, np.float32)
    assert "16x16" in (P.out_of_range({"irradiance": irr}) or "")
    assert P.out_of_range({"irradiance": np.full((P.MIN_SIDE, 64, 3), 0.5, np.float32)}) is None


def test_the_guard_bounds_are_chosen_by_the_promise_then_the_mean():
    """bench.plausible_choice's rule: no shot under the formula by more than 0.2 dB, then the highest mean; a test split
    is refused (the bounds are chosen on validation rooms only)."""
    from bench.plausible_choice import choose, main

    rows = [{"formula": 20.0, "tier1": 25.0, "auto": {(1.0, 0.2): 25.0, (2.0, 0.2): 26.0}},
            {"formula": 20.0, "tier1": 18.0, "auto": {(1.0, 0.2): 19.9, (2.0, 0.2): 18.5}}]
    res = choose(rows, (1.0, 2.0), (0.2,))
    assert [g["shots_under"] for g in res["grid"]] == [0, 1]  # the looser bound has the higher mean (22.25) but breaks the promise
    assert res["chosen"]["tile_bound"] == 1.0 and res["chosen"]["worst_vs_formula_db"] == pytest.approx(-0.1)
    assert choose(rows[1:], (2.0,), (0.2,))["chosen"] is None
    with pytest.raises(SystemExit, match="validation rooms only"):
        main(["--data", "anywhere", "--split", "test"])
