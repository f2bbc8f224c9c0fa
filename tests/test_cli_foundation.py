"""`x2video info / convert / edit` end to end on tiny generated shots."""
import json

import av
import numpy as np
import pytest

from x2video.cli import main
from x2video.edits import AlbedoSet, Edits, Mask, Project, save_project
from x2video.io import load_shot, write_shot_folder
from x2video.shot import ArrayShot

T, H, W = 3, 8, 10


@pytest.fixture
def shot_dir(tmp_path):
    rng = np.random.default_rng(0)
    n = np.zeros((T, H, W, 3))
    n[..., 2] = 1
    s = ArrayShot({"albedo": rng.random((T, H, W, 3)) * 0.5, "normal": n, "roughness": rng.random((T, H, W, 1)), "rgb": rng.random((T, H, W, 3)),
                   "ids": np.ones((T, H, W), np.int32)}, fps=8.0)
    return write_shot_folder(s, tmp_path / "shot")


def test_info(shot_dir, capsys):
    assert main(["info", str(shot_dir), "--json"]) == 0
    rep = json.loads(capsys.readouterr().out)
    assert rep["frames"] == T and rep["width"] == W and rep["format"] == "folder"
    assert rep["channels"] == ["albedo", "normal", "roughness", "rgb", "ids"] and rep["dropped"] == ["metallic", "irradiance"]
    assert 0 <= rep["ranges"]["albedo"][0] <= rep["ranges"]["albedo"][1] <= 0.5 + 1e-3
    assert main(["info", str(shot_dir)]) == 0
    assert "problems: none found" in capsys.readouterr().out


def test_info_reports_nan(shot_dir, capsys):
    from x2video.io.image import write_exr

    a = np.full((H, W), np.nan, np.float32)
    write_exr(shot_dir / "roughness" / "000001.exr", {"Y": a})
    assert main(["info", str(shot_dir), "--frames", "0"]) == 1  # it lists a problem
    assert "80 NaN/Inf value(s) in 'roughness'" in capsys.readouterr().out


def test_convert_all_formats(shot_dir, tmp_path):
    for fmt in ("folder", "multilayer", "png"):
        assert main(["convert", str(shot_dir), str(tmp_path / fmt), "--format", fmt]) == 0
        assert load_shot(tmp_path / fmt).num_frames == T
    assert main(["convert", str(shot_dir), str(tmp_path / "v.mp4"), "--fps", "5"]) == 0
    with av.open(str(tmp_path / "v.mp4")) as c:
        assert sum(1 for _ in c.decode(video=0)) == T
    assert main(["convert", str(shot_dir), str(tmp_path / "png"), "--format", "png"]) == 2  # exists, no --overwrite


def test_edit(shot_dir, tmp_path):
    m = Mask()
    box = np.zeros((H, W), np.float32)
    box[:4] = 1
    m.paint(1, box)
    edits = Edits(masks={"top": m}, ops=[AlbedoSet(mask="top", color=(1.0, 0.0, 0.0))], dropped={"roughness"})
    save_project(tmp_path / "p.json", Project(shot=str(shot_dir), edits=edits))
    assert main(["edit", str(shot_dir), str(tmp_path / "p.json"), str(tmp_path / "out")]) == 0
    out, src = load_shot(tmp_path / "out"), load_shot(shot_dir)
    assert "roughness" not in out.channels and "rgb" in out.channels
    np.testing.assert_allclose(out.channel("albedo", 1)[:4], np.broadcast_to([1.0, 0, 0], (4, W, 3)), atol=1e-3)
    assert np.array_equal(out.channel("albedo", 1)[4:], src.channel("albedo", 1)[4:])  # half -> half: exact
    assert np.array_equal(out.channel("albedo", 0), src.channel("albedo", 0))


def test_bad_input_exit_code(tmp_path, capsys):
    assert main(["info", str(tmp_path / "missing")]) == 2
    assert "missing: does not exist" in capsys.readouterr().err
