"""The editor's EXR export and `x2video render --out` share one writer (`FrameSink`): the same files, the same
channels and header, and the same resume rule (frames staged in `.NAME.resume`, kept by a re-run with the same key)."""
from __future__ import annotations

import errno
import json

import numpy as np
import pytest

from x2video.cli import main
from x2video.io.atomic import DiskFullError
from x2video.io.image import read_image
from x2video.render import frames as frames_mod

FRAMES = 4


@pytest.fixture()
def shot_dir(tmp_path):
    from x2video.io import write_shot_folder
    from x2video.shot import ArrayShot

    rng = np.random.default_rng(5)
    shot = ArrayShot({
        "albedo": rng.uniform(0.1, 0.9, (FRAMES, 16, 24, 3)).astype(np.float32),
        "irradiance": rng.uniform(0.2, 2.0, (FRAMES, 16, 24, 3)).astype(np.float32),
        "normal": np.broadcast_to(np.float32([0, 0, 1]), (FRAMES, 16, 24, 3)).copy(),
    })
    return write_shot_folder(shot, tmp_path / "shot")


def _editor_frames(shot_dir):
    from x2video.conditioning.edited import apply_edits
    from x2video.edits import Edits
    from x2video.formula import formula_frame
    from x2video.io import load_shot

    shot = load_shot(shot_dir)
    return shot, {t: formula_frame(apply_edits(shot, Edits(), t)) for t in range(shot.num_frames)}


def _cli(shot_dir, out):
    return main(["render", str(shot_dir), "--out", str(out), "--quality", "formula"])


def _export(shot_dir, out, edits=None):
    from x2video_app.state.exporter import export_exr

    shot, frames = _editor_frames(shot_dir)
    return list(export_exr(frames, out, shot, edits))


def _layout(folder):
    """Each file's name with its EXR channels, pixel types and header attributes (the layout, not the pixels)."""
    out = {}
    for p in sorted(folder.glob("*.exr")):
        img = read_image(p)
        out[p.name] = (sorted(img.channel_names), img.format, sorted(img.attributes))
    return out


def test_editor_export_and_cli_render_write_the_same_layout(shot_dir, tmp_path):
    assert _cli(shot_dir, tmp_path / "cli") == 0
    _export(shot_dir, tmp_path / "editor")
    cli, editor = _layout(tmp_path / "cli"), _layout(tmp_path / "editor")
    assert list(cli) == [f"{t:06d}.exr" for t in range(FRAMES)]
    assert editor == cli
    assert cli["000000.exr"][:2] == (["B", "G", "R"], "half")
    for t in range(FRAMES):  # the formula's frame, written by the same function: the same bytes
        name = f"{t:06d}.exr"
        assert (tmp_path / "cli" / name).read_bytes() == (tmp_path / "editor" / name).read_bytes(), name


def test_editor_export_with_channels_keeps_the_frames_layout(shot_dir, tmp_path):
    from x2video.edits import Edits
    from x2video.io import load_shot

    _export(shot_dir, tmp_path / "plain")
    _export(shot_dir, tmp_path / "edited", Edits())
    names = sorted(p.name for p in (tmp_path / "edited").iterdir())
    assert names == [*(f"{t:06d}.exr" for t in range(FRAMES)), "channels"]
    assert _layout(tmp_path / "edited") == _layout(tmp_path / "plain")
    back = load_shot(tmp_path / "edited" / "channels")
    assert back.num_frames == FRAMES and {"albedo", "irradiance", "normal"} <= set(back.channels)
    src = load_shot(shot_dir)
    np.testing.assert_allclose(back.channel("albedo", 2), src.channel("albedo", 2), atol=2e-3)


def _fail_after(monkeypatch, n):
    """Every EXR frame write after the first `n` fails as a full disk would."""
    real, calls = frames_mod.write_exr_frame, []

    def write(path, rgb, units, **kw):
        calls.append(path)
        if len(calls) > n:
            raise OSError(errno.ENOSPC, "No space left on device", str(path))
        real(path, rgb, units, **kw)

    monkeypatch.setattr(frames_mod, "write_exr_frame", write)


@pytest.mark.parametrize("with_channels", [False, True])
def test_editor_export_and_cli_render_resume_by_the_same_rule(shot_dir, tmp_path, monkeypatch, capsys, with_channels):
    from x2video.edits import Edits

    edits = Edits() if with_channels else None
    with monkeypatch.context() as m:
        _fail_after(m, 2)
        assert _cli(shot_dir, tmp_path / "cli") == 1
        assert "to resume" in capsys.readouterr().err
    with monkeypatch.context() as m:
        _fail_after(m, 2)
        with pytest.raises(DiskFullError, match="export into the same folder again to resume"):
            _export(shot_dir, tmp_path / "editor", edits)
    staged = {}
    for name in ("cli", "editor"):
        assert not (tmp_path / name).exists()  # nothing under the final name
        staging = tmp_path / f".{name}.resume"
        record = json.loads((staging / "resume.json").read_text())
        assert record["format"] == frames_mod.RESUME_FORMAT and record["output"] == name
        staged[name] = {p.name: p.stat().st_mtime_ns for p in staging.glob("[0-9]*.exr")}
    assert len(staged["cli"]) == 2  # the CLI renders keyframes first: which two is its order's business
    assert sorted(staged["editor"]) == ["000000.exr", "000001.exr"]

    assert _cli(shot_dir, tmp_path / "cli") == 0
    assert _export(shot_dir, tmp_path / "editor", edits)[-1] == FRAMES
    for name in ("cli", "editor"):
        assert not (tmp_path / f".{name}.resume").exists()
        assert all((tmp_path / name / n).stat().st_mtime_ns == t for n, t in staged[name].items())  # kept, not rewritten
    _export(shot_dir, tmp_path / "ref", edits)  # uninterrupted
    for t in range(FRAMES):
        name = f"{t:06d}.exr"
        assert (tmp_path / "editor" / name).read_bytes() == (tmp_path / "ref" / name).read_bytes() == (tmp_path / "cli" / name).read_bytes()
    if with_channels:
        assert sorted(p.name for p in (tmp_path / "editor" / "channels" / "albedo").iterdir()) == [f"{t:06d}.exr" for t in range(FRAMES)]


def test_an_export_never_empties_a_folder_of_other_files(shot_dir, tmp_path):
    out = tmp_path / "Desktop"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    with pytest.raises(ValueError, match="holds other files"):
        _export(shot_dir, out)
    assert (out / "notes.txt").read_text() == "mine"
    _export(shot_dir, tmp_path / "again")
    _export(shot_dir, tmp_path / "again")  # an earlier export is replaced
    assert len(list((tmp_path / "again").glob("*.exr"))) == FRAMES
