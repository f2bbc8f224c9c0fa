"""Mask propagation with DIS optical flow on a synthetic translating textured sequence."""
import cv2
import numpy as np

from x2video.edits import propagate_mask
from x2video.shot import ArrayShot

T, H, W = 11, 96, 128
DX, DY = 1.6, 0.7  # pixels per frame (sub-pixel, so bilinear resampling is exercised)


def _scene():
    rng = np.random.default_rng(3)
    big = rng.random((H, W, 3)).astype(np.float32)
    big = cv2.GaussianBlur(big, (0, 0), 1.5)
    big = (big - big.min()) / (big.max() - big.min())
    frames, masks = [], []
    for t in range(T):
        # the content moves by (+DX, +DY) per frame (mirrored border brings in new texture)
        A = np.float32([[1, 0, DX * t], [0, 1, DY * t]])
        frames.append(cv2.warpAffine(big, A, (W, H), flags=cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT_101))
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
