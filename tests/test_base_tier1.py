"""Tier 1's difference on the box around an edit (x2video.base.tier1, issue 52): inside the wanted pixels it
equals the whole-frame pass to float precision, for a net that uses its whole receptive field; the frame outside the
edit's reach stays the base bit for bit; the original frame's part is kept between frames of a drag and dropped when
the frame changes; the live preview's frame is the render's."""
from __future__ import annotations

import numpy as np
import pytest
import torch
from sampling_fake import FakeModel

from x2video.base.difference import SPILL_MARGIN, changed, edited_frame, grow
from x2video.base.tier1 import part_box, residual_difference
from x2video.conditioning.cache import ConditioningCache
from x2video.conditioning.edited import apply_edits
from x2video.conditioning.frame import plain_conditioning
from x2video.edits import Edits
from x2video.edits.masks import Mask
from x2video.model import residual as R
from x2video.model import residual_engine
from x2video.render.live import render_frame
from x2video.render.renderer import Renderer
from x2video.render.settings import RenderSettings
from x2video.render.timing import StageTimes
from x2video.shot import ArrayShot
from x2video.tiers.residual import residual_frames

WIDTHS = (8, 16, 32)  # three levels: receptive radius 26, a bottom cell's view 31 (`receptive_radius`)
TOL = 1e-5  # relative to the frame's largest value: float32 summation order, the whole frame's against the box's


def busy_net(seed: int = 0, widths: tuple[int, ...] = WIDTHS) -> R.ResidualNet:
    """A net whose output depends on its whole receptive field and its global context (the trained net's deeper
    levels may do nothing; this one's do)."""
    torch.manual_seed(seed)
    net = R.ResidualNet(R.ResidualConfig(widths=widths)).eval()
    for m in net.modules():
        if isinstance(m, torch.nn.Conv2d):
            torch.nn.init.kaiming_normal_(m.weight, nonlinearity="relu")
    torch.nn.init.normal_(net.out.weight, std=0.3)
    return net


def scene(h: int = 92, w: int = 133, t: int = 2, seed: int = 0) -> ArrayShot:
    """Five channels with structure everywhere (the net's context matters), a sky (no geometry: the formula is kept
    there), and a path-traced rgb; sizes that are not multiples of the net's factor."""
    rng = np.random.default_rng(seed)
    n = rng.normal(size=(t, h, w, 3)).astype(np.float32)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    n[:, :10, :40] = 0  # sky
    albedo = rng.uniform(0.1, 0.9, (t, h, w, 3)).astype(np.float32)
    irr = rng.uniform(0.2, 2.0, (t, h, w, 3)).astype(np.float32)
    return ArrayShot({"albedo": albedo, "irradiance": irr, "normal": n,
                      "roughness": rng.uniform(0.2, 0.8, (t, h, w, 1)).astype(np.float32),
                      "metallic": (rng.uniform(0, 1, (t, h, w, 1)) > 0.8).astype(np.float32),
                      "rgb": albedo * irr + 0.05}, irradiance_scale=1.0)


def rougher(h: int, w: int, where=(slice(40, 60), slice(70, 95)), value: float = 0.95) -> Edits:
    """Roughness set to `value` on an object (rougher than the scene's: tier 1's difference, not the formula's)."""
    m = np.zeros((h, w), np.float32)
    m[where] = 1
    e = Edits()
    e.masks["obj"] = Mask(frames={0: m}, hold=True)
    e.set_tuning("obj", "roughness_mode", "set")
    e.set_tuning("obj", "roughness", value)
    return e


def test_receptive_radius_is_the_gradients_support():
    for widths in ((8, 16), (8, 16, 32), (8, 8, 8, 8)):
        net = busy_net(widths=widths)
        radius, span = R.receptive_radius(net.cfg)
        f, size = net.cfg.factor, 4 * R.receptive_radius(net.cfg)[0] + 8 * net.cfg.factor
        lo = hi = 0
        for p in range(size // 2, size // 2 + f):  # every phase of the factor grid
            x = torch.randn(1, net.cfg.in_channels, f, size, requires_grad=True)
            x = x.expand(1, -1, f, -1).contiguous().detach().requires_grad_(True)
            net(x, torch.zeros(1, widths[-1]))[0, :, 0, p].sum().backward()
            cols = np.flatnonzero(x.grad.abs().sum((0, 1, 2)).numpy())
            lo, hi = min(lo, cols[0] - p), max(hi, cols[-1] - p)
        assert max(-lo, hi) == radius, widths
        x = torch.randn(1, net.cfg.in_channels, f, size, requires_grad=True)
        j = size // f // 2
        net.bottom(x)[0, :, 0, j].sum().backward()
        cols = np.flatnonzero(x.grad.abs().sum((0, 1, 2)).numpy())
        assert (f * j - cols[0]) + (cols[-1] - f * j) == span, widths


@pytest.mark.parametrize("engine", ["torch", "onnx"])
def test_the_box_equals_the_whole_frame_inside_the_reach(engine):
    if engine == "onnx":
        pytest.importorskip("onnxruntime")
    shot = scene()
    h, w = shot.size
    net = busy_net() if engine == "torch" else residual_engine.engine(busy_net(), "cpu", prefer="onnx")
    original, edited = plain_conditioning(shot, 0), apply_edits(shot, rougher(h, w), 0)
    reach = grow(changed(original, edited), SPILL_MARGIN)
    y0, y1, x0, x1 = part_box(reach, changed(original, edited), net.cfg.factor, *R.receptive_radius(net.cfg))
    assert (y1 - y0) * (x1 - x0) < 0.8 * h * w  # the box is a part of the frame
    got_e, got_o = residual_difference(net, original, edited, reach)
    want_e, want_o = residual_frames(net, [edited, original])
    scale = float(np.abs(want_e).max())
    assert float(np.abs(want_e - want_o)[reach].max()) > 0.05 * scale  # the edit changes tier 1's frame there
    for got, want in ((got_e, want_e), (got_o, want_o), (got_e - got_o, want_e - want_o)):
        assert float(np.abs(got - want)[reach].max()) <= TOL * scale
    # the rule for the pixels whose channels hold no light holds on the box: the formula there (the sky is in the box)
    sky = np.zeros((h, w), bool)
    sky[:10, :40] = True
    edge = apply_edits(shot, rougher(h, w, (slice(0, 20), slice(20, 60))), 0)
    where = grow(changed(original, edge), SPILL_MARGIN)
    got_e, _ = residual_difference(net, original, edge, where)
    want_e, _ = residual_frames(net, [edge, original])
    assert float(np.abs(got_e - want_e)[where].max()) <= TOL * scale and (where & sky).any()
    # the worst case, an edit of the whole frame: the box is the frame
    everything = apply_edits(shot, rougher(h, w, (slice(None), slice(None))), 0)
    got_e, got_o = residual_difference(net, original, everything, np.ones((h, w), bool))
    want_e, want_o = residual_frames(net, [everything, original])
    assert float(np.abs(got_e - want_e).max()) <= TOL * scale and float(np.abs(got_o - want_o).max()) <= TOL * scale


def test_over_the_base_the_box_gives_the_whole_frames_difference_and_the_base_elsewhere():
    shot = scene()
    h, w = shot.size
    net = busy_net()
    base = shot.channel("rgb", 0).astype(np.float64)
    original, edited = plain_conditioning(shot, 0), apply_edits(shot, rougher(h, w), 0)
    box, mode = edited_frame(base, original, edited, glossy_tier=True,
                             residual=lambda e, o, where: residual_difference(net, o, e, where))
    whole, mode_whole = edited_frame(base, original, edited, glossy_tier=True,
                                     residual=lambda e, o, where: tuple(residual_frames(net, [e, o])))
    assert mode == mode_whole == "formula+residual"
    reach = grow(changed(original, edited), SPILL_MARGIN)
    np.testing.assert_array_equal(box[~reach], base[~reach])  # bit for bit
    np.testing.assert_array_equal(whole[~reach], base[~reach])
    assert float(np.abs(box - whole).max()) <= TOL * float(np.abs(whole).max())
    assert float(np.abs(whole - base)[reach].max()) > 0.05  # and tier 1's difference is there


class CountingNet(R.ResidualNet):
    """A `busy_net` that counts its passes (the box's, and the bottom features')."""

    def __init__(self) -> None:
        super().__init__(R.ResidualConfig(widths=WIDTHS))
        self.load_state_dict(busy_net().state_dict())
        self.eval()
        self.parts = self.bottoms = 0

    def forward_part(self, *a):
        self.parts += 1
        return super().forward_part(*a)

    def bottom(self, x):
        self.bottoms += 1
        return super().bottom(x)


def test_the_originals_part_is_kept_while_the_edit_changes_and_dropped_when_the_frame_does():
    shot, other = scene(), scene(seed=1)
    h, w = shot.size
    net, counted = busy_net(), CountingNet()
    cache = ConditioningCache()
    original = plain_conditioning(shot, 0)
    first = None
    for k, value in enumerate((0.9, 0.92, 0.94)):  # a slider drag: the original frame's part is made once
        edited = apply_edits(shot, rougher(h, w, value=value), 0)
        reach = grow(changed(original, edited), SPILL_MARGIN)
        got = residual_difference(counted, original, edited, reach, cache=cache)
        want = residual_difference(net, original, edited, reach)  # no cache: everything made now
        for a, b in zip(got, want):
            np.testing.assert_array_equal(a, b)
        first = first or (counted.parts, counted.bottoms)
    assert first == (2, 2)  # the original's part and the edited box; the whole frame's bottom and the box's
    assert (counted.parts, counted.bottoms) == (4, 2)  # then the edited box alone
    # frame 0 of another shot (same index and size): its channels differ, so nothing kept is used
    original2 = plain_conditioning(other, 0)
    edited2 = apply_edits(other, rougher(h, w), 0)
    reach = grow(changed(original2, edited2), SPILL_MARGIN)
    got = residual_difference(counted, original2, edited2, reach, cache=cache)
    want = residual_difference(net, original2, edited2, reach)
    assert counted.parts == 6
    for a, b in zip(got, want):
        np.testing.assert_array_equal(a, b)


def test_a_live_preview_runs_the_net_once_a_frame_and_shows_the_renders_pixels():
    shot = scene(64, 96, t=3)
    h, w = shot.size
    model = FakeModel()
    model.residual_net = busy_net()
    settings = RenderSettings(quality="residual")
    live = Renderer(model)
    live.timing = StageTimes()
    frames = []
    for value in (0.9, 0.95):
        e = rougher(h, w, (slice(20, 40), slice(30, 60)), value)
        frames.append(render_frame(live, shot, e, settings, 1))
        assert frames[-1].tier == "residual" and live.timing.calls["residual"] == 1
    fresh = render_frame(Renderer(model, retain=False), shot, e, settings, 1)  # a render: nothing kept from before
    np.testing.assert_array_equal(frames[-1].image, fresh.image)
    assert float(np.abs(frames[0].image - frames[1].image).max()) > 0
