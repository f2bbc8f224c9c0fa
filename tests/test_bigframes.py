"""Large frames in bounded memory: tier 1 in overlapping tiles, the diffusion tier at a working resolution.

Kept fast: small nets and frames with the tile size shrunk, so that the tiled paths run as they do on
1920x1080 frames (where `bench/bigframes.py` measures them)."""
from __future__ import annotations

import numpy as np
import pytest
import torch
from sampling_fake import FakeModel

from x2video.conditioning.frame import FrameConditioning
from x2video.conditioning.network import UPSAMPLE, downsample_conditioning, resize_area, to_full, working_size
from x2video.formula import formula, formula_frame
from x2video.model import residual as R
from x2video.model import residual_engine
from x2video.render.events import FramesReady
from x2video.render.renderer import Renderer
from x2video.render.settings import RenderSettings
from x2video.shot import ArrayShot
from x2video.tiers.residual import residual_frames

pytestmark = pytest.mark.usefixtures("torch_one_thread")


def room_channels(h: int, w: int, seed: int = 0) -> dict[str, np.ndarray]:
    """Piecewise-constant channels (blocks of 9 pixels) with windows (normal 0): edges everywhere, as in a room."""
    import cv2

    rng = np.random.default_rng(seed)

    def blocks(c: int, lo: float, hi: float) -> np.ndarray:
        a = rng.uniform(lo, hi, (h // 9 + 1, w // 9 + 1, c)).astype(np.float32)
        return cv2.resize(a, (w, h), interpolation=cv2.INTER_NEAREST).reshape(h, w, c)

    n = blocks(3, -1, 1)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    n[blocks(1, 0, 1)[..., 0] > 0.9] = 0  # "windows"
    return {"albedo": blocks(3, 0, 1), "normal": n, "roughness": blocks(1, 0, 1), "metallic": (blocks(1, 0, 1) > 0.8).astype(np.float32),
            "irradiance": blocks(3, 0, 3)}


def deep_net(seed: int = 0, levels: int = 3) -> R.ResidualNet:
    """A small net (three levels: factor 4, a reach of about 25 pixels; the shipped net has four, factor 8, about
    50) with weights scaled so the deep levels and the global context matter: a tiling mistake shows."""
    torch.manual_seed(seed)
    net = R.ResidualNet(R.ResidualConfig(widths=(8, 16, 16, 16)[:levels])).eval()
    for m in net.modules():
        if isinstance(m, torch.nn.Conv2d):
            torch.nn.init.kaiming_normal_(m.weight, nonlinearity="relu")
    torch.nn.init.normal_(net.out.weight, std=0.3)
    torch.nn.init.normal_(net.context.weight, std=1.0)  # the frame's light reaches every pixel strongly
    return net


def whole(net, ch) -> np.ndarray:
    x, s = (torch.from_numpy(a)[None] for a in R.features(ch))
    with torch.inference_mode():
        return R.apply(net, x, s)[0].permute(1, 2, 0).numpy()


#: stated tolerance of tiles against the whole frame, in log1p units (float32 summation order)
TOL = 1e-4


class OwnContext:
    """A net whose tiles each take their own global context (what tiling must not do)."""

    def __init__(self, net):
        self.net, self.cfg = net, net.cfg
        self.bottom, self.context_vector = net.bottom, net.context_vector

    def __call__(self, x, g=None):
        return self.net(x)


def test_tiles_equal_the_whole_frame_and_shortcuts_do_not():
    net = deep_net()
    ch = room_channels(90, 133)  # not multiples of the factor: padded, cropped back
    want = whole(net, ch)
    got = R.apply_tiled(net, ch, tile=32, halo=32, feather=8)
    assert got.shape == want.shape == (90, 133, 3)
    assert float(np.abs(np.log1p(got) - np.log1p(want)).max()) < TOL
    short = R.apply_tiled(net, ch, tile=32, halo=4, feather=8)  # less context than the net's reach: seams
    assert float(np.abs(np.log1p(short) - np.log1p(want)).max()) > 10 * TOL
    own = R.apply_tiled(OwnContext(net), ch, tile=32, halo=32, feather=8)  # each tile's own light
    assert float(np.abs(np.log1p(own) - np.log1p(want)).max()) > 10 * TOL
    eng = residual_engine.engine(net, "cpu")
    assert isinstance(eng, residual_engine.OnnxResidual)
    onnx = R.apply_tiled(eng, ch, tile=32, halo=32, feather=8)
    assert float(np.abs(np.log1p(onnx) - np.log1p(want)).max()) < TOL


def test_the_shipped_depth_tiles_exactly_with_the_default_halo():
    net = deep_net(levels=4)  # factor 8, as shipped: HALO covers its reach
    ch = room_channels(150, 180)
    got = R.apply_tiled(net, ch, tile=80, halo=R.HALO, feather=R.FEATHER)
    assert float(np.abs(np.log1p(got) - np.log1p(whole(net, ch))).max()) < TOL


def test_tiles_with_dropped_channels_and_tiny_frames():
    net = deep_net(1)
    ch = room_channels(70, 90)
    ch["irradiance"] = None  # the formula is 0: the net's output alone
    want = whole(net, ch)
    assert float(np.abs(np.log1p(R.apply_tiled(net, ch, tile=32, halo=32)) - np.log1p(want)).max()) < TOL
    one = room_channels(5, 3)  # smaller than the factor
    assert float(np.abs(np.log1p(R.apply_tiled(net, one, tile=4, halo=4)) - np.log1p(whole(net, one))).max()) < TOL


@pytest.mark.parametrize("h,w,tile,halo", [(1088, 1920, 768, 64), (1024, 1024, 768, 64), (768, 1368, 768, 64), (40, 8, 16, 8),
                                           (8, 8, 768, 64), (4320, 7680, 768, 64)])
def test_tile_grid_partitions_the_frame_within_the_bound(h, w, tile, halo):
    f = 8
    tiles = R.tile_grid(h, w, tile, halo, f)
    owned = np.zeros((h, w), np.uint8)
    for t in tiles:
        y0, y1, x0, x1 = t.box
        cy0, cy1, cx0, cx1 = t.core
        assert all(v % f == 0 for v in (*t.box, *t.core))
        assert 0 <= y0 <= cy0 < cy1 <= y1 <= h and 0 <= x0 <= cx0 < cx1 <= x1 <= w
        assert cy1 - cy0 <= tile and cx1 - cx0 <= tile
        assert (y1 - y0) * (x1 - x0) <= (tile + 2 * halo) ** 2  # what one pass of the net sees: bounded by the tile
        assert cy0 - y0 == min(halo, cy0) and y1 - cy1 == min(halo, h - cy1)  # full context where the frame has it
        owned[cy0:cy1, cx0:cx1] += 1
    assert (owned == 1).all()
    with pytest.raises(ValueError, match="factor"):
        R.tile_grid(h, w, tile + 4, halo, f)


@pytest.mark.parametrize("feather", [0, 16, 32])
def test_blend_weights_sum_to_one(feather):
    h, w = 96, 200
    total = np.zeros((h, w))
    for t in R.tile_grid(h, w, 64, 32, 8):
        y0, y1, x0, x1 = t.box
        wy, wx = R._ramp(y0, y1, t.core[0], t.core[1], h, feather), R._ramp(x0, x1, t.core[2], t.core[3], w, feather)
        total[y0:y1, x0:x1] += wy[:, None] * wx[None, :]
    np.testing.assert_allclose(total, 1.0, atol=1e-6)


def test_needs_tiles():
    assert not R.needs_tiles((896, 896), 8)
    assert R.needs_tiles((1024, 1024), 8) and R.needs_tiles((768, 1366), 8) and R.needs_tiles((1080, 1920), 8)
    assert not R.needs_tiles((112, 160), 8)
    assert R.needs_tiles((100, 100), 8, max_pixels=100 * 100 - 1)


class Spy:
    """Wraps a tier-1 net and records the pixels of every pass."""

    def __init__(self, net):
        self.net, self.cfg, self.pixels = net, net.cfg, []

    def __call__(self, x, g=None):
        self.pixels.append(x.shape[0] * x.shape[2] * x.shape[3])
        return self.net(x, g)

    def bottom(self, x):
        self.pixels.append(x.shape[0] * x.shape[2] * x.shape[3])
        return self.net.bottom(x)

    def context_vector(self, m):
        return self.net.context_vector(m)


def test_a_large_shot_renders_through_tiles_in_bounded_passes(monkeypatch):
    """A 90x133 shot with the tile shrunk to 32 goes through the Renderer as a 1366x768 one does with the default
    tile: no pass of the net sees more than MAX_PIXELS, and the frames equal the whole-frame pass."""
    monkeypatch.setattr(R, "TILE", 32)
    monkeypatch.setattr(R, "HALO", 32)
    monkeypatch.setattr(R, "FEATHER", 8)
    monkeypatch.setattr(R, "MAX_PIXELS", (32 + 2 * 32) ** 2)
    frames = [room_channels(90, 133, seed) for seed in range(3)]
    shot = ArrayShot({k: np.stack([f[k] for f in frames]) for k in frames[0]})
    model = FakeModel()
    model.residual_net = Spy(deep_net())
    got = {}
    settings = RenderSettings(quality="residual", guess_unseen=True)  # the net's own output, compared with the whole-frame pass
    Renderer(model).render(shot, None, settings, lambda e: got.update(e.frames) if isinstance(e, FramesReady) else None)
    assert sorted(got) == [0, 1, 2]
    assert max(model.residual_net.pixels) <= R.MAX_PIXELS
    for t in range(3):
        assert float(np.abs(np.log1p(got[t]) - np.log1p(whole(model.residual_net.net, shot.frame(t)))).max()) < TOL
    # small frames batch together, never over the bound either
    small = [FrameConditioning(channels={k: v[:40, :48] for k, v in f.items()}, amr_mask=np.zeros((40, 48), np.float32),
                               local_masks=np.zeros((0, 40, 48), np.float32), frame_index=i) for i, f in enumerate(frames)]
    model.residual_net.pixels.clear()
    out = residual_frames(model.residual_net, small, batch=16, guess_unseen=True)
    assert model.residual_net.pixels == [3 * 40 * 48] and len(out) == 3  # MAX_PIXELS // (40 * 48) = 4 frames a pass: one


def test_working_size():
    assert working_size((112, 160), 4, 320 * 224) is None
    assert working_size((1080, 1920), 4, 0) is None
    for size in ((1080, 1920), (1024, 1024), (768, 1366), (4000, 30)):
        h, w = working_size(size, 4, 320 * 224)
        assert h % 4 == 0 and w % 4 == 0 and h * w <= 320 * 224
        s = (320 * 224 / (size[0] * size[1])) ** 0.5  # both sides scaled alike (the aspect kept), floored to the factor grid
        assert size[0] * s - 4 < h <= size[0] * s and size[1] * s - 4 < w <= size[1] * s


def _cond(ch: dict, h: int, w: int) -> FrameConditioning:
    return FrameConditioning(channels=dict(ch), amr_mask=np.zeros((h, w), np.float32), local_masks=np.zeros((0, h, w), np.float32), frame_index=0)


def test_to_full_keeps_the_formulas_detail_and_the_networks_residual():
    h, w = 120, 200
    ch = room_channels(h, w)
    full = _cond(ch, h, w)
    small = downsample_conditioning(full, (30, 50))
    assert small.channels["albedo"].shape == (30, 50, 3) and small.amr_mask.shape == (30, 50)
    n = np.linalg.norm(small.channels["normal"], axis=-1)
    assert np.all((np.abs(n - 1) < 1e-4) | (n == 0))
    base = formula_frame(full)
    # a network that adds nothing over the (area-averaged) formula gives the full-resolution formula back, detail and all
    same = to_full(resize_area(base, (30, 50)), full)
    np.testing.assert_allclose(same, base, rtol=1e-4, atol=1e-4)
    # a network that doubles the light gives twice... in log1p space: the residual rides on the full-resolution formula
    brighter = to_full(np.expm1(np.log1p(resize_area(base, (30, 50))) + 0.5), full)
    np.testing.assert_allclose(np.log1p(brighter) - np.log1p(base), 0.5, atol=2e-3)
    guided = to_full(np.expm1(np.log1p(resize_area(base, (30, 50))) + 0.5), full, upsample="guided")
    np.testing.assert_allclose(np.log1p(guided) - np.log1p(base), 0.5, atol=2e-3)
    # without irradiance there is no formula: the network's frame itself comes up (guided: by the albedo)
    ch2 = dict(ch, irradiance=None)
    for mode in UPSAMPLE:
        up = to_full(np.full((30, 50, 3), 0.25, np.float32), _cond(ch2, h, w), upsample=mode)
        assert up.shape == (h, w, 3)
        np.testing.assert_allclose(up, 0.25, atol=1e-3)
    with pytest.raises(ValueError, match="upsampling"):
        to_full(base, full, upsample="nearest")


def test_large_diffusion_frames_run_at_the_working_resolution():
    """The diffusion sampler sees working-size conditioning; the frames come back at full size."""
    h, w = 60, 100
    shot = ArrayShot({k: np.stack([room_channels(h, w, s)[k] for s in range(2)]) for k in room_channels(h, w)})
    model = FakeModel()
    sizes = []
    encode = model.encode_frames
    model.encode_frames = lambda frames: (sizes.extend(f.size for f in frames), encode(frames))[1]
    got = {}

    def on(e):
        if isinstance(e, FramesReady):
            got.update(e.frames)

    Renderer(model).render(shot, None, RenderSettings(quality="diffusion", steps=2, working_pixels=24 * 40), on)
    assert set(sizes) == {(24, 40)}
    assert sorted(got) == [0, 1] and got[0].shape == (h, w, 3) and np.isfinite(got[0]).all()
    sizes.clear()
    Renderer(model).render(shot, None, RenderSettings(quality="diffusion", steps=2, working_pixels=0), on)
    assert set(sizes) == {(64, 104)}  # full size, reflect-padded to the factor 8
    with pytest.raises(ValueError, match="working_pixels"):
        Renderer(model).render(shot, None, RenderSettings(quality="diffusion", steps=2, working_pixels=-1), on)


class ConstantNet:
    """A tier-1 net whose correction is the same everywhere: log1p(frame) = log1p(formula) + c."""

    def __init__(self, c: float):
        self.c, self.cfg = c, R.ResidualConfig(widths=(8, 16, 16))  # factor 4

    def __call__(self, x, g=None):
        return torch.full((x.shape[0], 3, x.shape[2], x.shape[3]), self.c)


def test_large_tier1_frames_run_at_the_working_resolution(caplog):
    """Above `residual_pixels` the tier-1 net sees working-size channels; its correction comes back onto the
    full-resolution formula, whose detail stays."""
    h, w = 60, 100
    shot = ArrayShot({k: np.stack([room_channels(h, w, s)[k] for s in range(2)]) for k in room_channels(h, w)})
    model = FakeModel()
    model.residual_net = Spy(ConstantNet(0.3))
    got: dict[int, np.ndarray] = {}

    def on(e):
        if isinstance(e, FramesReady):
            got.update(e.frames)

    with caplog.at_level("INFO", logger="x2video"):
        Renderer(model).render(shot, None, RenderSettings(quality="residual", guess_unseen=True, residual_pixels=24 * 40), on)
    assert "shot size 100x60: the tier-1 net runs at 40x24" in caplog.text
    assert model.residual_net.pixels == [24 * 40, 24 * 40]  # 60x100 scaled by 0.4 on the factor-4 grid, the first frame alone
    for t in range(2):
        base = formula(shot.frame(t))
        assert got[t].shape == (h, w, 3) and base.std() > 0.1
        np.testing.assert_allclose(np.log1p(got[t]) - np.log1p(base), 0.3, atol=1e-4)  # every full-resolution edge kept
    # without irradiance there is no formula: the net's own (working-size) frame comes up
    dark = residual_frames(ConstantNet(0.3), [_cond(dict(shot.frame(0), irradiance=None), h, w)], guess_unseen=True, max_pixels=24 * 40)[0]
    assert dark.shape == (h, w, 3)
    np.testing.assert_allclose(dark, np.expm1(0.3), rtol=1e-5)
    model.residual_net.pixels.clear()
    Renderer(model).render(shot, None, RenderSettings(quality="residual", guess_unseen=True, residual_pixels=0), on)
    assert model.residual_net.pixels == [h * w, h * w]  # at full size
    model.residual_net.pixels.clear()
    Renderer(model).render(shot, None, RenderSettings(quality="residual", guess_unseen=True), on)
    assert model.residual_net.pixels == [h * w, h * w]  # the default bound (512x512) leaves this frame alone
    with pytest.raises(ValueError, match="residual_pixels"):
        Renderer(model).render(shot, None, RenderSettings(quality="residual", residual_pixels=-1), on)


def test_tier1_at_working_size_is_close_to_full_size_on_smooth_light():
    """With a real (deep) net, the working-size pass differs from the full-size one by what the bilinear upsampling
    of its correction loses, not by a misplaced, rescaled or flattened correction."""
    net = deep_net(levels=3)
    h, w = 96, 160
    ch = room_channels(h, w, 4)
    full = residual_frames(net, [_cond(ch, h, w)], guess_unseen=True)[0]
    small = residual_frames(net, [_cond(ch, h, w)], guess_unseen=True, max_pixels=48 * 80)[0]
    base = np.log1p(formula(ch))
    flat = base + (np.log1p(full) - base).mean((0, 1))  # the right correction's frame mean everywhere
    err = np.abs(np.log1p(small) - np.log1p(full)).mean()
    assert small.shape == full.shape and err < 0.8 * np.abs(flat - np.log1p(full)).mean() and err < 0.5 * np.abs(base - np.log1p(full)).mean()


class WindowNet:
    """A tier-1 net that guesses +2 (log space) where there is no geometry (windows) and corrects nothing else."""

    def __init__(self):
        self.cfg = R.ResidualConfig(widths=(8, 16, 16))

    def __call__(self, x, g=None):
        return 2.0 * (1 - x[:, 19:20]).expand(-1, 3, -1, -1)  # plane 19: geometry


def test_no_bright_rim_around_windows_at_working_size():
    """The net's guess in a window must not spread onto the wall around it when its correction is upsampled
    (it did: +0.22 in log1p, 24 % brighter, next to windows at 2.5x)."""
    h, w = 120, 200
    ch = room_channels(h, w, 5)
    n = np.zeros_like(ch["normal"])
    n[..., 2] = 1
    n[np.linalg.norm(ch["normal"], axis=-1) < 0.5] = 0  # smooth walls with windows
    ch["normal"] = n
    geo = n[..., 2] > 0
    assert 0.05 < (~geo).mean() < 0.2
    base = np.log1p(formula(ch))
    for pixels in (0, 48 * 80):
        got = residual_frames(WindowNet(), [_cond(ch, h, w)], max_pixels=pixels)[0]
        assert float(np.abs(np.log1p(got) - base)[geo].max()) < 1e-5, pixels
    guess = residual_frames(WindowNet(), [_cond(ch, h, w)], max_pixels=48 * 80, guess_unseen=True)[0]
    assert float((np.log1p(guess) - base)[~geo].mean()) > 1.0  # asked for, the guess is there


class DarkNet:
    """A tier-1 net that darkens everything by more than any formula's light."""

    def __init__(self):
        self.cfg = R.ResidualConfig(widths=(8, 16, 16))

    def __call__(self, x, g=None):
        return torch.full((x.shape[0], 3, x.shape[2], x.shape[3]), -5.0)


def test_working_size_brings_up_the_nets_correction_not_its_clipped_frame():
    rng = np.random.default_rng(0)
    h, w = 60, 100
    al = np.zeros((h, w, 3), np.float32)
    al[:, ::2] = 0.2  # one-pixel stripes: the working size averages them
    ch = {"albedo": al, "irradiance": np.full((h, w, 3), 0.1, np.float32), "normal": np.dstack([np.zeros((h, w, 2)), np.ones((h, w))]).astype(np.float32),
          "roughness": rng.uniform(0, 1, (h, w, 1)).astype(np.float32), "metallic": np.zeros((h, w, 1), np.float32)}
    for pixels in (0, 24 * 40):
        assert float(residual_frames(DarkNet(), [_cond(ch, h, w)], max_pixels=pixels)[0].max()) == 0.0, pixels
