"""`x2video render`: a smoke render of a shot folder with untrained tiny weights, and its clear errors."""
from __future__ import annotations

import av
import pytest
from sampling_fake import make_shot

from x2video.cli import main
from x2video.io import write_shot_folder

pytestmark = pytest.mark.usefixtures("torch_one_thread")


@pytest.fixture(scope="module")
def shot_dir(tmp_path_factory):
    return write_shot_folder(make_shot(6, height=32, width=48), tmp_path_factory.mktemp("shot") / "shot")


def test_render_untrained_to_mp4_and_exr(shot_dir, tmp_path, capsys) -> None:
    out = tmp_path / "out.mp4"
    assert main(["render", str(shot_dir), "--out", str(out), "--untrained", "--steps", "1", "--window", "3", "--device", "cpu", "--seams"]) == 0
    with av.open(str(out)) as c:
        frames = [f for f in c.decode(video=0)]
    assert len(frames) == 6 and (frames[0].width, frames[0].height) == (48, 32)
    assert "wrote 6 frames" in capsys.readouterr().out
    # a project file (its shot path, its edits) instead of SHOT; EXR folder output
    from x2video.edits import Edits, Project, save_project

    proj = tmp_path / "p" / "scene.json"
    proj.parent.mkdir()
    save_project(proj, Project(shot=str(shot_dir), edits=Edits(global_prompt="warm evening", dropped={"normal"})))
    exr = tmp_path / "exr"
    args = ["render", "--project", str(proj), "--out", str(exr), "--untrained", "--preset", "fast", "--frames", "2:5", "--scheme", "sequential",
            "--no-replace-refs"]
    from x2video.render.renderer import Renderer

    seen, render = [], Renderer.render
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(Renderer, "render", lambda self, shot, edits, settings, *a, **k: (seen.append(settings), render(self, shot, edits, settings, *a, **k))[1])
        assert main(args) == 0
    assert [s.replace_refs for s in seen] == [False]  # on by default (RenderSettings); the flag turns it off
    assert sorted(p.name for p in exr.iterdir()) == ["000002.exr", "000003.exr", "000004.exr"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["exr", "out.mp4", "p"]  # no staging left behind


def test_missing_weights_says_how_to_get_them(shot_dir, tmp_path, capsys, monkeypatch) -> None:
    import x2video.weights as weights

    monkeypatch.delenv("X2VIDEO_WEIGHTS", raising=False)
    monkeypatch.setattr(weights, "_candidates", lambda: [tmp_path / "resources" / "x2video-tiny"])
    assert weights.shipped_weights() is None
    assert main(["render", str(shot_dir), "--out", str(tmp_path / "o.mp4")]) == 2
    err = capsys.readouterr().err
    assert "no trained weights" in err and "--untrained" in err and "x2video train" in err
    assert not (tmp_path / "o.mp4").exists()


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--frames", "4:99"], "frame range"),
        (["--window", "1"], "window size"),
        (["--sampler", "lcm", "--steps", "2"], "LCM weights"),
    ],
)
def test_bad_settings(shot_dir, tmp_path, capsys, extra, message) -> None:
    args = ["render", str(shot_dir), "--out", str(tmp_path / "o.mp4"), "--untrained", "--steps", "1", *extra]
    assert main(args) == 2
    assert message in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def test_missing_shot(tmp_path, capsys) -> None:
    assert main(["render", str(tmp_path / "nope"), "--out", str(tmp_path / "o.mp4"), "--untrained"]) == 2
    assert "nope" in capsys.readouterr().err
