"""x2video.render.live (issue 43): the tiers a live preview runs follow `tiers.decide`, and `render_frame` renders one
frame through `Renderer.render` (a per-frame tier: that frame; the sampler: its window around the frame)."""
from __future__ import annotations

import numpy as np
import pytest
import torch
from sampling_fake import FakeModel, make_shot
from test_tiers import full_shot

from x2video.conditioning.edited import apply_edits
from x2video.edits import Edits
from x2video.formula import formula_frame
from x2video.model import residual as R
from x2video.render.events import CancelToken
from x2video.render.live import frame_window, preview_choice, render_frame
from x2video.render.renderer import Renderer
from x2video.render.settings import RenderSettings
from x2video.tiers.residual import residual_frames

pytestmark = pytest.mark.usefixtures("torch_one_thread")


def with_net() -> FakeModel:
    m = FakeModel()
    torch.manual_seed(0)
    m.residual_net = R.ResidualNet(R.ResidualConfig(widths=(8, 16))).eval()
    torch.nn.init.normal_(m.residual_net.out.weight, std=0.1)  # not the zero init: the net must change frames
    return m


def local_prompt(shot) -> Edits:
    e = Edits.for_shot(shot)
    e.add_mask("m")
    e.masks["m"].paint(0, np.ones(shot.size, np.float32))
    e.masks["m"].hold = True
    e.set_local_prompt("m", "a brass lamp")
    return e


def test_the_preview_is_the_per_frame_tier_the_render_runs_or_stands_in_for_it():
    shot = full_shot(6)
    net, plain = with_net(), FakeModel()
    c = preview_choice("auto", shot, None, net)  # nothing to generate: tier 1 is both
    assert c.preview.tier == c.full.tier == "residual" and c.same
    c = preview_choice("auto", shot, local_prompt(shot), net)  # a local prompt: the sampler inside, tier 1 around
    assert (c.preview.tier, c.full.tier, c.full.base, c.same) == ("residual", "diffusion", "residual", False)
    assert "stands in for the diffusion sampler" in c.preview.reason
    c = preview_choice("auto", shot, None, plain)  # no tier-1 net: the sampler renders, the formula stands in
    assert (c.preview.tier, c.full.tier) == ("formula", "diffusion")
    c = preview_choice("formula", shot, None, net)
    assert c.preview.tier == c.full.tier == "formula" and c.same
    c = preview_choice("auto", shot, None, None)  # the model is not built: the formula, and no full quality yet
    assert c.preview.tier == "formula" and c.full is None and not c.same and "needs a model" in c.preview.reason
    c = preview_choice("auto", make_shot(6), None, net)  # no roughness or metallic: auto renders the formula itself
    assert c.preview.tier == c.full.tier == "formula" and c.same


def test_frame_window_holds_the_frame_inside_the_shot():
    assert frame_window(0, 33, 5) == (0, 5) and frame_window(16, 33, 5) == (14, 19) and frame_window(32, 33, 5) == (28, 33)
    assert frame_window(2, 3, 5) == (0, 3)


def test_render_frame_renders_that_frame_with_the_decided_tier():
    shot = full_shot(6)
    e = Edits.for_shot(shot)
    e.set_tuning(None, "exposure", 1.0)
    net = with_net()
    r = Renderer(net)
    f = render_frame(r, shot, e, RenderSettings(quality="formula"), 3)
    assert f.tier == "formula" and f.frames == (3, 4)
    np.testing.assert_allclose(f.image, formula_frame(apply_edits(shot, e, 3)), rtol=1e-6)
    f = render_frame(r, shot, e, RenderSettings(), 3)
    assert f.tier == "residual" and f.frames == (3, 4)
    np.testing.assert_allclose(f.image, residual_frames(net.residual_net, [apply_edits(shot, e, 3)])[0], rtol=1e-5, atol=1e-6)
    f = render_frame(r, shot, local_prompt(shot), RenderSettings(preset="fast", window=3), 4)  # the sampler, over its window
    assert f.tier == "diffusion" and f.frames == (3, 6) and f.image.shape == (*shot.size, 3)
    token = CancelToken()
    token.cancel()
    assert render_frame(r, shot, local_prompt(shot), RenderSettings(preset="fast", window=3), 4, token) is None
