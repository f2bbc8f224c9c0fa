"""Mask propagation with DIS optical flow on a synthetic translating textured sequence."""
import numpy as np

from x2video.edits import propagate_mask
from x2video.shot import ArrayShot

T, H, W = 11, 96, 128
DX, DY = 2, 1  # pixels per frame


def _scene():
    rng = np.random.default_rng(3)
    big = rng.random((H + 40, W + 60, 3)).astype(np.float32)
    import cv2

    big = cv2.GaussianBlur(big, (0, 0), 1.5)
    big = (big - big.min()) / (big.max() - big.min())
    frames, masks = [], []
    for t in range(T):
        # camera pans: content moves by (+DX, +DY) per frame
        y0, x0 = 20 - DY * t, 30 - DX * t
        frames.append(big[y0 : y0 + H, x0 : x0 + W])
        m = np.zeros((H, W), np.float32)
        cy, cx = 40 + DY * t, 50 + DX * t
        yy, xx = np.mgrid[:H, :W]
        m[(yy - cy) ** 2 + (xx - cx) ** 2 < 18**2] = 1
        masks.append(m)
    return ArrayShot({"albedo": np.stack(frames)}), masks


def _iou(a, b):
    a, b = a > 0.5, b > 0.5
    return (a & b).sum() / (a | b).sum()


def test_forward_and_backward():
    shot, masks = _scene()
    seen = []
    out = propagate_mask(shot, masks[0], 0, on_progress=lambda d, n: seen.append((d, n)))
    assert sorted(out) == list(range(T)) and seen[-1] == (T - 1, T - 1)
    ious = [_iou(out[t], masks[t]) for t in range(T)]
    assert ious[10] >= 0.9, ious
    # a mask that stayed put would score far lower: the test can fail
    assert _iou(masks[0], masks[10]) < 0.6
    back = propagate_mask(shot, masks[10], 10, frames=[0, 5])
    assert sorted(back) == [0, 5] and _iou(back[0], masks[0]) >= 0.9
    stopped = propagate_mask(shot, masks[0], 0, should_stop=lambda: True)
    assert sorted(stopped) == [0]
