"""Hostile command lines and inputs to `x2video render`, run in-process through `main(argv)`: each gives a clear
error (exit 2 for bad input, 1 for the machine) with no traceback, and leaves no output, or renders a valid shot."""
from __future__ import annotations

import dataclasses
import json
import shutil

import numpy as np
import pytest
from faults_helpers import FORMULA, assert_no_partial_files, tiny_shot_dir

from x2video.cli import main
from x2video.render.settings import RenderSettings

QUALITIES = ["auto", "formula", "residual", "diffusion"]


def run_cli(argv, capsys):
    try:
        code = main(argv)
    except SystemExit as exc:  # argparse's own errors (a flag's type, a choice)
        code = exc.code
    out = capsys.readouterr()
    assert "Traceback" not in out.err and "Traceback" not in out.out, out.err
    return code, out.err


def refused(argv, capsys, tmp_path, match, code=2):
    """`argv` exits with `code`, says `match` on one line of stderr, and writes nothing under tmp_path/out*."""
    got, err = run_cli(argv, capsys)
    assert got == code, (got, err)
    assert match in err, err
    assert "error" in err
    assert not [p for p in tmp_path.iterdir() if p.name.startswith("out")], list(tmp_path.iterdir())
    for p in tmp_path.glob(".out*"):  # a failed render keeps whole frames only, for a re-run to resume from
        assert p.name.endswith(".resume"), p
        assert_no_partial_files(p)


@pytest.mark.parametrize("quality", QUALITIES)
def test_steps_zero_is_refused_under_every_quality(quality, shot_dir, tmp_path, capsys):
    """Issue 44: `--steps 0` exited 0 because 'auto' picked tier 1, which takes no steps."""
    refused(["render", str(shot_dir), "--out", str(tmp_path / "out"), "--steps", "0", "--quality", quality], capsys, tmp_path,
            "steps must be at least 1, got 0")


BAD_FLAGS = [
    (["--steps", "-3"], "steps must be at least 1"),
    (["--window", "1"], "window size must be at least 2"),
    (["--window", "0", *FORMULA], "window size must be at least 2"),
    (["--frames", "3:3"], "the range 3:3 is empty"),
    (["--frames", "3:1"], "the range 3:1 is empty"),
    (["--frames=-1:2"], "START must be 0 or more"),
    (["--frames", "0:99", *FORMULA], "outside the shot's 4 frames"),
    (["--frames", "two:three"], "wants START:STOP"),
    (["--seed", "-1", *FORMULA], "seed must be 0 or more"),
    (["--noise-shared", "nan"], "noise_shared: expected a finite number"),
    (["--noise-shared", "1.5", *FORMULA], "noise_shared must lie in [0, 1]"),
    (["--ref-dc", "-0.5", *FORMULA], "ref_dc must lie in [0, 1]"),
    (["--resample", "0", *FORMULA], "resample must be at least 1"),
    (["--max-levels", "0", *FORMULA], "max_levels must be at least 1"),
    (["--working-pixels", "-1", *FORMULA], "working_pixels must be 0"),
    (["--residual-pixels", "-5"], "residual_pixels must be 0"),
    (["--exposure", "nan", *FORMULA], "not a finite number of stops"),
    (["--steps", "abc"], "invalid int value"),
    (["--quality", "best"], "invalid choice"),
]


@pytest.mark.parametrize(("flags", "match"), BAD_FLAGS, ids=[" ".join(f) for f, _ in BAD_FLAGS])
def test_bad_flags_are_refused_before_anything_is_written(flags, match, shot_dir, tmp_path, capsys):
    refused(["render", str(shot_dir), "--out", str(tmp_path / "out"), *flags], capsys, tmp_path, match)


@pytest.mark.parametrize("fps", ["0", "-2", "inf"])
def test_bad_frame_rate_is_refused(fps, shot_dir, tmp_path, capsys):
    refused(["render", str(shot_dir), "--out", str(tmp_path / "out.mp4"), "--fps", fps, *FORMULA], capsys, tmp_path,
            "fps must be a positive number")


def test_library_api_refuses_the_same_values():
    """The settings object itself refuses them, so the Python API, the farm and the editor get the same protection."""
    with pytest.raises(ValueError, match="steps must be at least 1"):
        RenderSettings(steps=0, quality="formula")
    ok = RenderSettings(quality="formula")
    with pytest.raises(ValueError, match="the range 5:5 is empty"):
        dataclasses.replace(ok, frames=(5, 5))
    ok.steps = 0  # changed in place: validate() says so, and the Renderer calls it before choosing a tier
    with pytest.raises(ValueError, match="steps"):
        ok.validate()
    from sampling_fake import make_shot

    from x2video.render.events import RenderFailed
    from x2video.render.renderer import Renderer

    events: list = []
    with pytest.raises(ValueError, match="steps must be at least 1"):
        Renderer(None).render(make_shot(3), None, ok, on_event=events.append)
    assert isinstance(events[-1], RenderFailed) and not [e for e in events if hasattr(e, "frames")]
    with pytest.raises(ValueError, match="unknown quality 'best'"):  # any registered tier is a quality: the render says
        Renderer(None).render(make_shot(3), None, RenderSettings(quality="best"))  # type: ignore[arg-type]


def test_output_inside_a_file(shot_dir, tmp_path, capsys):
    (tmp_path / "afile").write_text("x")
    got, err = run_cli(["render", str(shot_dir), "--out", str(tmp_path / "afile" / "out"), *FORMULA], capsys)
    assert got == 2 and "afile is a file" in err and (tmp_path / "afile").read_text() == "x"


def test_output_folder_where_a_file_is(shot_dir, tmp_path, capsys):
    (tmp_path / "out").write_text("keep me")
    got, err = run_cli(["render", str(shot_dir), "--out", str(tmp_path / "out"), *FORMULA], capsys)
    assert got == 2 and "exists and is a file" in err and (tmp_path / "out").read_text() == "keep me"


def test_missing_and_empty_shot_folders(tmp_path, capsys):
    refused(["render", str(tmp_path / "nope"), "--out", str(tmp_path / "out"), *FORMULA], capsys, tmp_path, "nope")
    (tmp_path / "empty").mkdir()
    refused(["render", str(tmp_path / "empty"), "--out", str(tmp_path / "out"), *FORMULA], capsys, tmp_path, "empty")


def test_bad_shot_json(shot_dir, tmp_path, capsys):
    shot = shutil.copytree(shot_dir, tmp_path / "shot")
    (shot / "shot.json").write_text('{"format": "x2video-shot", "version": 1, "num_frames": ')
    refused(["render", str(shot), "--out", str(tmp_path / "out"), *FORMULA], capsys, tmp_path, "shot.json: not valid JSON")


def test_bad_project_files(shot_dir, tmp_path, capsys):
    from x2video.edits import Edits, Project, save_project

    proj = tmp_path / "p.x2v.json"
    save_project(proj, Project(shot=str(shot_dir), edits=Edits(global_prompt="x")))
    text = proj.read_text()
    proj.write_text(text[: len(text) // 2])  # truncated
    refused(["render", "--project", str(proj), "--out", str(tmp_path / "out"), *FORMULA], capsys, tmp_path, "p.x2v.json: not valid JSON")
    doc = json.loads(text)
    proj.write_text(json.dumps({**doc, "version": 99}))
    refused(["render", "--project", str(proj), "--out", str(tmp_path / "out"), *FORMULA], capsys, tmp_path, "newer than this x2video")
    proj.write_text(json.dumps({**doc, "shot": str(tmp_path / "gone")}))
    refused(["render", "--project", str(proj), "--out", str(tmp_path / "out"), *FORMULA], capsys, tmp_path, "gone")
    proj.write_text(json.dumps({**doc, "edits": {"masks": {}, "ops": [{"op": "exposure", "mask": "ghost", "stops": 1}]}}))
    refused(["render", "--project", str(proj), "--out", str(tmp_path / "out"), *FORMULA], capsys, tmp_path, "ghost")


def test_frames_of_different_sizes(shot_dir, tmp_path, capsys):
    from x2video.io.image import write_exr

    shot = shutil.copytree(shot_dir, tmp_path / "shot")
    a = np.full((20, 30), 0.5, np.float32)
    write_exr(shot / "albedo" / "000002.exr", {"R": a, "G": a, "B": a})
    refused(["render", str(shot), "--out", str(tmp_path / "out"), *FORMULA], capsys, tmp_path, "000002.exr: size 30x20")


def test_garbage_and_truncated_frames(shot_dir, tmp_path, capsys):
    shot = shutil.copytree(shot_dir, tmp_path / "shot")
    data = (shot / "irradiance" / "000001.exr").read_bytes()
    (shot / "irradiance" / "000001.exr").write_bytes(data[: len(data) - 300])
    refused(["render", str(shot), "--out", str(tmp_path / "out"), *FORMULA], capsys, tmp_path, "000001.exr")
    (shot / "irradiance" / "000001.exr").write_bytes(b"this is not an EXR file")
    refused(["render", str(shot), "--out", str(tmp_path / "out"), *FORMULA], capsys, tmp_path, "000001.exr")


def test_gap_in_frame_numbers(shot_dir, tmp_path, capsys):
    shot = shutil.copytree(shot_dir, tmp_path / "shot")
    (shot / "normal" / "000002.exr").unlink()
    refused(["render", str(shot), "--out", str(tmp_path / "out"), *FORMULA], capsys, tmp_path, "normal")


def test_missing_channel_renders(shot_dir, tmp_path, capsys):
    """A channel missing is a dropped channel, never an error: the formula needs only albedo and irradiance."""
    shot = tiny_shot_dir(tmp_path / "shot", normal=None)
    got, err = run_cli(["render", str(shot), "--out", str(tmp_path / "out"), *FORMULA], capsys)
    assert got == 0, err
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == [f"{t:06d}.exr" for t in range(4)]
    assert_no_partial_files(tmp_path / "out")


def test_nan_and_inf_channels_render_finite_frames(tmp_path, capsys):
    from faults_helpers import tiny_arrays

    from x2video.io.image import read_image

    arrays = tiny_arrays()
    arrays["irradiance"][:, 2:6, 3:9] = np.nan
    arrays["irradiance"][:, 8:10, 3:9] = np.inf
    arrays["albedo"][:, 12:14, :4] = -np.inf
    shot = tiny_shot_dir(tmp_path / "shot", **arrays)
    with pytest.warns(RuntimeWarning, match="NaN/Inf"):
        got, err = run_cli(["render", str(shot), "--out", str(tmp_path / "out"), *FORMULA], capsys)
    assert got == 0, err
    for p in (tmp_path / "out").iterdir():
        img = read_image(p).all()
        assert np.isfinite(img).all() and (img[2:6, 3:9] == 0).all(), p


@pytest.mark.parametrize("extra", [[], ["--openjd", "templates"]], ids=["ray", "openjd"])
def test_the_farm_refuses_the_same_flags_before_it_starts(extra, shot_dir, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    refused(["farm", str(shot_dir), "--out", str(tmp_path / "out"), "--steps", "0", *extra], capsys, tmp_path,
            "steps must be at least 1, got 0")
    assert not (tmp_path / "templates").exists()
