"""Bad inputs: each gives an error (or warning) that names the culprit file, frame or field."""
import json
import shutil

import numpy as np
import pytest

from x2video.io import ShotWriter, load_shot
from x2video.io.image import write_exr, write_ldr
from x2video.shot import ShotInfo

H, W = 4, 6


def _good(root, T=3, channels=("albedo", "roughness")):
    info = ShotInfo(num_frames=T, height=H, width=W, channels=())
    with ShotWriter(root, info) as w:
        for t in range(T):
            w.write_frame(t, {c: np.full((H, W, 3 if c == "albedo" else 1), 0.5, np.float32) for c in channels})
    return root


def _rgb(path, h=H, w=W):
    write_exr(path, {c: np.full((h, w), 0.5, np.float32) for c in "RGB"})


def frame_count(r):
    _good(r)
    (r / "roughness" / "000002.exr").unlink()
    return r, r"roughness: 2 frames, but shot.json has 3"


def size_mismatch(r):
    _good(r)
    for t in range(3):
        _rgb(r / "albedo" / f"{t:06d}.exr", 5, 6)
    return r, r"albedo/000000.exr: size 6x5, but shot.json says 6x4"


def size_mid_sequence(r):
    _good(r)
    _rgb(r / "albedo" / "000002.exr", 8, 6)
    return r, r"albedo/000002.exr: size 6x8, the shot is 6x4"


def corrupt(r):
    _good(r)
    (r / "albedo" / "000001.exr").write_bytes(b"not an exr at all" * 10)
    return r, r"albedo/000001.exr: cannot (open|read)"


def truncated(r):
    _good(r)
    p = r / "albedo" / "000001.exr"
    data = p.read_bytes()
    p.write_bytes(data[: len(data) // 2])
    return r, r"albedo/000001.exr: cannot (open|read)"


def wrong_channels(r):
    _good(r)
    write_exr(r / "albedo" / "000001.exr", {"Y": np.zeros((H, W), np.float32), "A": np.zeros((H, W), np.float32)})
    return r, r"albedo/000001.exr: cannot take the 3 component\(s\) of 'albedo'"


def empty_folder(r):
    _good(r)
    shutil.rmtree(r / "roughness")
    (r / "roughness").mkdir()
    return r, r"roughness: empty"


def gap(r):
    for t in (0, 1, 3):
        write_ldr(r / "albedo" / f"f{t:03d}.png", np.zeros((H, W, 3)))
    return r, r"albedo: gap in frame numbering: f001.png is followed by f003.png"


def unnumbered(r):
    write_ldr(r / "albedo" / "f000.png", np.zeros((H, W, 3)))
    write_ldr(r / "albedo" / "cover.png", np.zeros((H, W, 3)))
    return r, r"cover.png: file name has no frame number"


def mixed(r):
    write_ldr(r / "albedo" / "f000.png", np.zeros((H, W, 3)))
    write_ldr(r / "albedo" / "f001.jpg", np.zeros((H, W, 3)))
    return r, r"albedo: mixed sequences: f000.png and f001.jpg"


def duplicate(r):
    write_ldr(r / "albedo" / "f0.png", np.zeros((H, W, 3)))
    write_ldr(r / "albedo" / "f00.png", np.zeros((H, W, 3)))
    return r, r"frame number 0 appears twice"


def bad_json(r):
    _good(r)
    (r / "shot.json").write_text("{\"num_frames\": 3,")
    return r, r"shot.json: not valid JSON"


def newer_version(r):
    _good(r)
    d = json.loads((r / "shot.json").read_text())
    d["version"] = 9
    (r / "shot.json").write_text(json.dumps(d))
    return r, r"shot.json: field 'version' is 9"


def bad_field(r):
    _good(r)
    d = json.loads((r / "shot.json").read_text())
    d["fps"] = -3
    (r / "shot.json").write_text(json.dumps(d))
    return r, r"shot.json: field 'fps' must be a positive number"


def cameras_short(r):
    _good(r)
    (r / "cameras.json").write_text(json.dumps({"frames": [{"frame": 0, "cam_to_world": np.eye(4).tolist()}]}))
    return r, r"cameras.json: no camera pose for frame\(s\) \[1, 2\]"


def cameras_not_matrix(r):
    _good(r)
    (r / "cameras.json").write_text(json.dumps({"frames": [{"frame": t, "cam_to_world": [[1, 0], [0, 1]]} for t in range(3)]}))
    return r, r"cameras.json: frames\[0\].cam_to_world is not a finite 4x4 matrix"


def missing_path(r):
    return r / "nope", r"nope: does not exist"


def nothing_known(r):
    (r / "notes.txt").write_text("hi")
    return r, r"no shot found"


def unknown_passes(r):
    write_exr(r / "f0.exr", {"Layer.Foo.R": np.zeros((H, W), np.float32)})
    return r, r"f0.exr: no known passes"


def xrgb_inconsistent(r):
    for n in ("a_1", "a_2"):
        write_ldr(r / f"{n}-albedo.png", np.zeros((H, W, 3)))
    write_ldr(r / "a_1-normal.png", np.zeros((H, W, 3)))
    return r, r"set 'a_2' has channels \['albedo'\]"


CASES = [
    frame_count, size_mismatch, size_mid_sequence, corrupt, truncated, wrong_channels, empty_folder, gap, unnumbered,
    mixed, duplicate, bad_json, newer_version, bad_field, cameras_short, cameras_not_matrix, missing_path, nothing_known,
    unknown_passes, xrgb_inconsistent,
]


@pytest.mark.parametrize("case", CASES, ids=[c.__name__ for c in CASES])
def test_bad_input(tmp_path, case):
    root = tmp_path / "shot"
    root.mkdir()
    path, message = case(root)
    with pytest.raises((ValueError, FileNotFoundError), match=message):
        shot = load_shot(path)
        for t in range(shot.num_frames):
            shot.frame(t)


def test_nan_inf_zeroed_with_count(tmp_path):
    r = _good(tmp_path / "s")
    a = np.full((H, W), 0.5, np.float32)
    a[0, :3] = np.nan
    a[1, 0] = np.inf
    write_exr(r / "albedo" / "000001.exr", {"R": a, "G": a, "B": a})
    shot = load_shot(r)
    with pytest.warns(RuntimeWarning, match=r"albedo/000001.exr \(frame 1\): 12 NaN/Inf value\(s\) in 'albedo' set to 0"):
        x = shot.channel("albedo", 1)
    assert np.isfinite(x).all() and x[0, 0, 0] == 0 and x[2, 2, 0] == 0.5


def test_clamped_to_range(tmp_path):
    r = _good(tmp_path / "s")
    write_exr(r / "albedo" / "000000.exr", {c: np.full((H, W), v, np.float32) for c, v in zip("RGB", (1.5, -0.2, 0.3))})
    shot = load_shot(r)
    np.testing.assert_allclose(shot.channel("albedo", 0)[0, 0], [1.0, 0.0, 0.3], atol=1e-3)


def test_missing_openimageio_fails_at_the_first_read_and_says_so(tmp_path, monkeypatch):
    """Without OpenImageIO (a lent GPU image) x2video still imports; reading an image names what is missing."""
    import x2video.io.image as image

    path = tmp_path / "a.exr"
    write_exr(path, {"R": np.zeros((4, 4), np.float32)})
    monkeypatch.setattr(image, "oiio", image._Missing("OpenImageIO", ImportError("No module named 'OpenImageIO'")))
    with pytest.raises(ImportError, match="OpenImageIO is not installed.*reading and writing images needs it"):
        image.read_image(path)
