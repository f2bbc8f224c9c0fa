"""TC: flow-warping error with exact motion or DIS flow, occlusion masks, and the motion reader."""
import numpy as np
import pytest

from x2video.metrics.motion_io import read_motion
from x2video.metrics.temporal import (
    dis_flows,
    flows_from_motion,
    forward_backward_mask,
    temporal_consistency,
    warp_back,
    warping_errors,
)

T, H, W = 5, 48, 64
V = (1.5, 0.75)  # pixels per frame, x right, y down


def texture(dx: float, dy: float, seed: int) -> np.ndarray:
    """A smooth random sum of sinusoids, translated by (dx, dy): exact at sub-pixel shifts."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:H, 0:W].astype(np.float64)
    x, y = x - dx, y - dy
    img = np.zeros((H, W, 3))
    for c in range(3):
        for _ in range(6):
            fx, fy = rng.uniform(0.03, 0.12, 2) * rng.choice([-1, 1], 2)
            img[..., c] += np.sin(2 * np.pi * (fx * x + fy * y) + rng.uniform(0, 2 * np.pi))
    return (0.5 + img / 14).clip(0, 1).astype(np.float32)


def video(seed: int) -> list[np.ndarray]:
    return [texture(V[0] * t, V[1] * t, seed) for t in range(T)]


def exact_motion() -> np.ndarray:
    m = np.zeros((T - 1, H, W, 2), np.float32)
    m[..., 0], m[..., 1] = V
    return m


def flicker(frames):
    return [np.clip(f + (0.05 if t % 2 else -0.05), 0, 1) for t, f in enumerate(frames)]


def test_warp_back_integer_shift_is_exact():
    img = np.random.default_rng(0).uniform(size=(H, W, 3)).astype(np.float32)
    flow = np.zeros((H, W, 2), np.float32)
    flow[..., 0] = 3.0  # out(x) = img(x + 3)
    out = warp_back(img, flow)
    np.testing.assert_array_equal(out[:, : W - 3], img[:, 3:])


@pytest.mark.parametrize("use_motion", [True, False])
def test_ground_truth_scores_one_and_flicker_scores_higher(use_motion):
    gt = video(0)
    motion = exact_motion() if use_motion else None
    same = temporal_consistency(gt, gt, motion)
    assert same.tc == 1.0 and same.pairs == T - 1
    assert same.flow_source == ("exact" if use_motion else "dis")
    assert temporal_consistency(flicker(gt), gt, motion).tc > 3.0


def test_dis_on_translating_sequence():
    gt, other = video(0), video(1)  # another texture moving the same way: as consistent as the ground truth
    flows = dis_flows(gt)
    med = np.median(flows[0].flow[flows[0].valid], axis=0)
    np.testing.assert_allclose(med, V, atol=0.15)
    assert flows[0].valid.mean() > 0.8
    res = temporal_consistency(other, gt)
    assert 0.8 < res.tc < 1.25
    # the same content without motion is inconsistent with the ground-truth flow
    frozen = [other[0]] * T
    assert temporal_consistency(frozen, gt).tc > 3.0


def test_exact_motion_sign_convention_and_nan_mask():
    gt, other = video(0), video(1)
    good = temporal_consistency(other, gt, exact_motion())
    flipped = temporal_consistency(other, gt, -exact_motion())
    assert good.gt_error < 0.02 < flipped.gt_error  # motion is displacement of frame t's pixels to t+1
    # NaN marks occluded / out-of-view pixels: they leave the mask
    motion = exact_motion()
    motion[:, 10:30, 20:40] = np.nan
    res = temporal_consistency(other, gt, motion)
    assert res.valid_fraction < 1.0 - (20 * 20) / (H * W) + 1e-9
    fl = flows_from_motion(motion, T, (H, W))
    assert not fl[0].valid[10:30, 20:40].any()
    assert not fl[0].valid[:, W - 1].any()  # x + 1.5 leaves the image on the right


def test_nan_region_is_ignored():
    gt = video(0)
    motion = exact_motion()
    motion[:, 10:30, 20:40] = np.nan
    flows = flows_from_motion(motion, T, (H, W))
    # corrupt frames where only masked pixels look (as frame t or, 1 px inside, as warped t+1)
    corrupt = [f.copy() for f in gt]
    for f in corrupt[::2]:
        f[12:28, 22:38] = 0.0
    a, b = warping_errors(gt, flows), warping_errors(corrupt, flows)
    np.testing.assert_allclose(a.errors, b.errors)
    # the same corruption outside the masked block is seen
    corrupt2 = [f.copy() for f in gt]
    for f in corrupt2[::2]:
        f[12:28, 42:58] = 0.0
    assert warping_errors(corrupt2, flows).mean > 5 * a.mean


def test_forward_backward_check():
    fwd = np.zeros((H, W, 2), np.float32)
    fwd[..., 0] = 2.0
    assert forward_backward_mask(fwd, -fwd).all()
    assert not forward_backward_mask(fwd, fwd).any()


def test_bad_inputs_name_the_problem():
    gt = video(0)
    with pytest.raises(ValueError, match="expected 4 fields"):
        temporal_consistency(gt, gt, exact_motion()[:2])
    with pytest.raises(ValueError, match="motion frame 0"):
        temporal_consistency(gt, gt, np.zeros((T - 1, H, W + 1, 2), np.float32))
    with pytest.raises(ValueError, match="prediction has 4 frames"):
        temporal_consistency(gt[:4], gt)


def _write_exr(path, data, names):
    import OpenImageIO as oiio

    spec = oiio.ImageSpec(data.shape[1], data.shape[0], data.shape[2], oiio.FLOAT)
    spec.channelnames = names
    out = oiio.ImageOutput.create(str(path))
    assert out.open(str(path), spec)
    out.write_image(np.ascontiguousarray(data))
    out.close()


def test_read_motion_round_trip(tmp_path):
    assert read_motion(tmp_path) is None
    (tmp_path / "motion").mkdir()
    m = np.random.default_rng(0).normal(size=(3, 6, 8, 2)).astype(np.float32)
    m[1, 2, 3] = np.nan
    for t in range(3):
        _write_exr(tmp_path / "motion" / f"{t:06d}.exr", m[t], ("X", "Y"))
    got = read_motion(tmp_path, num_frames=4)
    np.testing.assert_array_equal(got, m)
    # channels are found by name, whatever their order in the file
    _write_exr(tmp_path / "motion" / "000000.exr", m[0][..., ::-1].copy(), ("motion.Y", "motion.X"))
    np.testing.assert_array_equal(read_motion(tmp_path)[0], m[0])
    with pytest.raises(ValueError, match="need 4"):
        read_motion(tmp_path, num_frames=5)
    (tmp_path / "motion" / "000001.exr").unlink()
    with pytest.raises(ValueError, match="without gaps"):
        read_motion(tmp_path)
