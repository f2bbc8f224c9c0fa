"""Issue 43's look-dev views: an A/B wipe, side by side and a false-colour difference between two versions of the frame
on screen (formula and tier 1 made off the GUI thread), and PSNR against the shot's ground truth in the status bar."""
from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("PySide6")
pytest.importorskip("pytestqt")

from test_app_live_preview import TIMEOUT_MS, shot_dir, win  # noqa: E402,F401 - the fixtures

from x2video.channels import tonemap  # noqa: E402
from x2video_app.state.compare_views import compose, difference, wipe  # noqa: E402
from x2video_app.state.display import to_u8  # noqa: E402


def test_wipe_and_difference_compose_two_images():
    a, b = np.zeros((4, 10, 3), np.uint8), np.full((4, 10, 3), 200, np.uint8)
    w = wipe(a, b, 0.3)
    assert (w[:, :2] == 0).all() and (w[:, 4:] == 200).all() and (w[:, 2:4] == 230).all()
    x = np.random.default_rng(0).uniform(0, 1, (4, 10, 3)).astype(np.float32)
    same = difference(x, x)
    assert (same == same[0, 0]).all() and same[0, 0].sum() < 20  # equal: one dark colour
    far = difference(x * 0, x * 0 + 1)
    assert far[0, 0].sum() > 500  # a full-scale difference: near white-yellow
    assert compose("side by side", x, x).shape == (4, 24, 3)


def test_a_b_wipe_of_formula_and_tier_1_and_psnr_against_the_ground_truth(qtbot, win):
    from x2video.conditioning.edited import apply_edits
    from x2video.formula import formula_frame
    from x2video.tiers.residual import residual_frames

    cmp = win.compare
    win.edits.set_param("exposure", 0.5, True)
    cmp.a.setCurrentIndex(cmp.a.findData("formula"))
    cmp.b.setCurrentIndex(cmp.b.findData("tier 1"))
    cmp.mode.setCurrentIndex(cmp.mode.findData("wipe"))
    qtbot.waitUntil(lambda: "rendering" not in cmp.label.text() and "tier 1" in cmp.label.text() and win.live.idle, timeout=TIMEOUT_MS)
    assert cmp.label.isVisible() and cmp.label.text().startswith("A: formula | B: tier 1")
    cond = apply_edits(win.doc.shot, win.doc.edits, win.doc.frame)
    fa, fb = tonemap(formula_frame(cond)), tonemap(residual_frames(win.model.residual_net, [cond])[0])
    shown = cmp.image_or(lambda: None)
    assert np.array_equal(shown, wipe(to_u8(fa), to_u8(fb), 0.5))
    cmp.mode.setCurrentIndex(cmp.mode.findData("difference"))
    assert np.array_equal(cmp.image_or(lambda: None), difference(fa, fb))
    # the shot's rgb channel is its ground truth: the status bar gives each version's PSNR on this frame
    truth = tonemap(win.doc.shot.channel("rgb", win.doc.frame).astype(np.float32) * np.float32(win.doc.shot.info.irradiance_scale))
    want = 10 * np.log10(1 / np.mean((fb.astype(np.float64) - truth) ** 2))
    assert cmp.psnr["tier 1"] == pytest.approx(want, abs=1e-6) and "PSNR vs ground truth" in cmp.psnr_label.text()
    assert "tier 1" in cmp.psnr_label.text() and "rendered" in cmp.psnr  # the live preview's frame
    cmp.mode.setCurrentIndex(cmp.mode.findData("off"))
    assert not cmp.label.isVisible() and np.array_equal(win.doc.display_image(), cmp.image_or(win.doc.display_image))


def test_the_ground_truth_is_compared_in_the_renders_exposure(qtbot, win):
    """A loader that normalised the irradiance (irradiance_scale; about 16 on the Cycles demo) left the rgb in the file's
    units; the renders are in the normalised exposure, so Compare scales the ground truth as training does. Unscaled,
    the demo's Cycles frame showed dark beside every render and PSNR read ~5 dB."""
    doc = win.doc
    doc.shot.info.irradiance_scale = 4.0
    got, label = win.compare.source("ground truth")
    want = tonemap(doc.shot.channel("rgb", doc.frame).astype(np.float32) * 4.0)
    assert label.startswith("ground truth") and np.allclose(got, want)
