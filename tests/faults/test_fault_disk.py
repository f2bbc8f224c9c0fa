"""A full disk under `x2video render --out`, the farm's chunk task, the editor's export and autosave: a clear message
naming the folder and the space needed, no partial file, the frames written before kept whole, and a re-run that
resumes and ends with exactly what an uninterrupted render writes. `small_disk` is a real tmpfs where this machine
allows a mount (root), else a simulated full disk; each test records which ran."""
from __future__ import annotations

import logging

import numpy as np
import pytest
from faults_helpers import FORMULA, assert_no_partial_files, folder_bytes, tiny_shot_dir

from x2video.cli import main
from x2video.io.atomic import DiskFullError

FRAMES, H, W = 6, 48, 64  # about 17 KB a frame as a half-float EXR of noisy colours (4-5 tmpfs pages)


@pytest.fixture(scope="module")
def big_shot(tmp_path_factory):
    return tiny_shot_dir(tmp_path_factory.mktemp("disk") / "shot", frames=FRAMES, h=H, w=W, seed=3)


def cli(argv, capsys):
    code = main(argv)
    err = capsys.readouterr().err
    assert "Traceback" not in err
    return code, err


def test_render_to_a_full_disk_stops_clearly_and_resumes_bit_for_bit(big_shot, small_disk, tmp_path, capsys, caplog):
    disk = small_disk(40 * 1024)
    out = disk.path / "out"
    code, err = cli(["render", str(big_shot), "--out", str(out), *FORMULA], capsys)
    assert code == 1, err
    line = err.strip().splitlines()[-1]
    assert f"no space left in {disk.path}" in line and "is needed" in line and "free" in line, line
    assert "kept in" in line and "run the same command again to resume" in line, line
    assert not out.exists()  # nothing under the final name
    staging = disk.path / ".out.resume"
    kept = sorted(p.name for p in staging.glob("[0-9]*.exr"))
    assert 1 <= len(kept) < FRAMES, kept
    assert_no_partial_files(disk.path)  # every staged frame reads whole; no temporary left

    disk.grow(1024 * 1024)  # the person frees space
    with caplog.at_level(logging.INFO, logger="x2video.cli.render"):
        code, err = cli(["render", str(big_shot), "--out", str(out), *FORMULA], capsys)
    assert code == 0, err
    assert f"{len(kept)} of {FRAMES} frames kept from the last attempt" in caplog.text
    assert not staging.exists()
    ref = tmp_path / "ref"
    assert cli(["render", str(big_shot), "--out", str(ref), *FORMULA], capsys)[0] == 0
    assert folder_bytes(out) == folder_bytes(ref)  # the resumed render's files are the uninterrupted one's, byte for byte


def test_mp4_encode_on_a_full_disk_leaves_no_partial_file(big_shot, small_disk, tmp_path, capsys):
    ref = tmp_path / "ref.mp4"
    assert cli(["render", str(big_shot), "--out", str(ref), *FORMULA], capsys)[0] == 0
    staged = FRAMES * (H * W * 3 * 2 + 128)  # float16 frames staged before the encode
    disk = small_disk(staged + 8 * 1024)  # room for the staged frames and resume.json, not for the MP4 as well
    out = disk.path / "out.mp4"
    code, err = cli(["render", str(big_shot), "--out", str(out), *FORMULA], capsys)
    assert code == 1 and f"no space left in {disk.path}" in err, err
    assert not out.exists() and not list(disk.path.glob("*.tmp.mp4")) and not list(disk.path.glob(".*.tmp.mp4"))
    assert_no_partial_files(disk.path)
    disk.grow(1024 * 1024)
    code, err = cli(["render", str(big_shot), "--out", str(out), *FORMULA], capsys)
    assert code == 0, err
    assert out.read_bytes() == ref.read_bytes()
    assert [p.name for p in disk.path.iterdir()] == ["out.mp4"]


def test_farm_chunk_on_a_full_disk_keeps_whole_frames_and_resumes(big_shot, small_disk, tmp_path, capsys):
    from x2video.farm import chunks, state, task
    from x2video.farm.jobs import Job
    from x2video.render.settings import RenderSettings
    from x2video.weights import ModelOptions

    settings, options = RenderSettings(quality="formula"), ModelOptions()
    job = Job(name="shot", source=big_shot, kind="shot")
    disk = small_disk(48 * 1024)
    out = disk.path
    key = chunks.digest(state.job_key(job, settings, options, "exr", None))
    chunks.begin(out, job.name, key)
    with pytest.raises(DiskFullError) as info:
        task.render_chunk(job, out, settings, options, "exr", (0, FRAMES), key)
    msg = str(info.value)
    assert str(chunks.frames_dir(out, "shot")) in msg and "is needed" in msg and "run the same farm command again" in msg, msg
    assert_no_partial_files(out)
    disk.grow(1024 * 1024)
    task.render_chunk(job, out, settings, options, "exr", (0, FRAMES), key)  # Ray's retry or the next farm run
    target = chunks.assemble(out, job.name, "exr", list(range(FRAMES)), None, 10.0)  # type: ignore[arg-type]
    ref = tmp_path / "ref"
    assert cli(["render", str(big_shot), "--out", str(ref), *FORMULA], capsys)[0] == 0
    assert folder_bytes(target) == folder_bytes(ref)


def _frames(shot_dir):
    from x2video.conditioning.edited import apply_edits
    from x2video.edits import Edits
    from x2video.formula import formula_frame
    from x2video.io import load_shot

    shot = load_shot(shot_dir)
    return shot, {t: formula_frame(apply_edits(shot, Edits(), t)) for t in range(shot.num_frames)}


def test_editor_exr_export_on_a_full_disk_resumes(big_shot, small_disk, tmp_path):
    from x2video_app.state.exporter import export_exr

    shot, frames = _frames(big_shot)
    disk = small_disk(60 * 1024)
    out = disk.path / "export"
    with pytest.raises(DiskFullError) as info:
        list(export_exr(frames, out, shot))
    msg = str(info.value)
    assert f"no space left in {disk.path}" in msg and "export into the same folder again to resume" in msg, msg
    assert not out.exists()  # nothing under the final name: staged beside it, as a CLI render is
    staging = disk.path / ".export.resume"
    assert_no_partial_files(disk.path)
    written = {p.name: p.stat().st_mtime_ns for p in staging.glob("[0-9]*.exr")}
    assert 1 <= len(written) < FRAMES
    disk.grow(1024 * 1024)
    assert list(export_exr(frames, out, shot))[-1] == FRAMES
    assert all((out / n).stat().st_mtime_ns == m for n, m in written.items())  # kept, not written again
    assert not staging.exists() and not (out / "resume.json").exists()
    ref = tmp_path / "ref"
    list(export_exr(frames, ref, shot))
    assert folder_bytes(out) == folder_bytes(ref)  # the resumed export's files are the uninterrupted one's


def test_editor_mp4_export_on_a_full_disk(big_shot, small_disk):
    from x2video_app.state.exporter import export_mp4

    _, frames = _frames(big_shot)
    disk = small_disk(8 * 1024)
    with pytest.raises(DiskFullError) as info:
        list(export_mp4(frames, disk.path / "a.mp4", 10.0))
    assert f"no space left in {disk.path}" in str(info.value) and "nothing was written" in str(info.value)
    assert list(disk.path.iterdir()) == []


def test_autosave_on_a_full_disk_keeps_the_last_whole_one(small_disk):
    from faults_helpers import edits_digest

    from x2video.edits import Edits
    from x2video.edits.autosave import Autosave, read_autosave, snapshot, write_autosave

    disk = small_disk(64 * 1024)
    side = disk.path / "p.x2v.autosave.json"
    rng = np.random.default_rng(0)
    edits, last = Edits(), None
    edits.add_mask("m")
    with pytest.raises(OSError) as info:
        for t in range(200):  # noisy mask frames do not compress: the disk fills after a few
            edits = snapshot(edits)
            edits.masks["m"].paint(t, rng.random((H, W)))
            write_autosave(side, Autosave(shot="/s", states=[edits]))
            last = edits_digest(edits)
    assert info.value.errno == 28 or isinstance(info.value, DiskFullError)
    assert last is not None
    assert edits_digest(read_autosave(side).current) == last  # the previous autosave, whole
    assert_no_partial_files(disk.path)
