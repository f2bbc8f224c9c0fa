"""Input files that change while a render reads them (a shot folder re-rendered by Blender, or deleted): the render
stops with an error naming the file and the frame, never a crash, never a frame made of old and new files; nothing
is written under the output's name."""
from __future__ import annotations

import os
import shutil
import time

import numpy as np
import pytest
from faults_helpers import FORMULA, assert_no_partial_files

from x2video.cli import main
from x2video.io import load_shot
from x2video.io.image import ImageReadError, ShotChangedError, write_exr
from x2video.render.frames import FrameSink


def _vanish(p):
    p.unlink()


def _truncate(p):
    data = p.read_bytes()
    with open(p, "r+b") as f:  # in place, as a writer that has not finished yet
        f.truncate(len(data) // 2)


def _rewrite_in_place(p):
    a = np.full((24, 32), 0.25, np.float32)
    write_exr(p.with_name(".tmp.exr"), {"R": a, "G": a, "B": a})
    data = p.with_name(".tmp.exr").read_bytes()
    p.with_name(".tmp.exr").unlink()
    time.sleep(0.01)  # a new modification time even on coarse clocks
    with open(p, "wb") as f:
        f.write(data)


def _rewrite_by_rename(p):
    a = np.full((24, 32), 0.75, np.float32)
    write_exr(p.with_name("new.exr"), {"R": a, "G": a, "B": a})
    os.replace(p.with_name("new.exr"), p)  # an atomic writer (ours, Blender's): a new inode under the old name


CHANGES = {"vanishes": (_vanish, "removed after the shot was opened"), "is truncated": (_truncate, "changed after the shot was opened"),
           "is rewritten in place": (_rewrite_in_place, "changed after the shot was opened"),
           "is replaced by a rename": (_rewrite_by_rename, "changed after the shot was opened")}


@pytest.mark.parametrize("change", list(CHANGES))
def test_a_frame_that_changes_during_a_render_is_named(change, shot_dir, tmp_path):
    import x2video

    shot_path = shutil.copytree(shot_dir, tmp_path / "shot")
    shot = load_shot(shot_path)
    victim = shot_path / "irradiance" / "000003.exr"
    do, says = CHANGES[change]
    done = []
    sink = FrameSink(tmp_path / "out", fps=10, expected=list(range(4)))

    def on_event(event):
        frames = getattr(event, "frames", None)
        if isinstance(frames, dict) and 0 in frames and not done:
            do(victim)  # frame 0 is out; frame 3 is read later
            done.append(change)
        sink(event)

    with pytest.raises(ImageReadError) as info:
        x2video.Renderer(None).render(shot, None, x2video.RenderSettings(quality="formula"), on_event=on_event)
    assert done, "the render read frame 3 before frame 0 was out"
    msg = str(info.value)
    assert str(victim) in msg and "frame 3" in msg and says in msg, msg
    assert isinstance(info.value, ShotChangedError)
    assert not (tmp_path / "out").exists()
    for p in tmp_path.glob(".out*"):  # whole frames only, kept for a re-run
        assert_no_partial_files(p)


def test_a_file_rewritten_under_the_cli_exits_cleanly(shot_dir, tmp_path, capsys, monkeypatch):
    shot_path = shutil.copytree(shot_dir, tmp_path / "shot")
    victim = shot_path / "albedo" / "000002.exr"
    real_add = FrameSink.add

    def add(self, index, rgb, **kw):
        if index == 0:
            _rewrite_by_rename(victim)
        return real_add(self, index, rgb, **kw)

    monkeypatch.setattr(FrameSink, "add", add)
    code = main(["render", str(shot_path), "--out", str(tmp_path / "out"), *FORMULA])
    err = capsys.readouterr().err
    assert code == 2 and "Traceback" not in err, err
    assert f"{victim} (frame 2): the file changed after the shot was opened" in err, err
    assert not (tmp_path / "out").exists()
    for p in tmp_path.glob(".out*"):  # whole frames only, kept for a re-run
        assert_no_partial_files(p)


def test_unchanged_files_read_as_before_and_a_reopened_shot_reads_the_new_ones(shot_dir, tmp_path):
    shot_path = shutil.copytree(shot_dir, tmp_path / "shot")
    shot = load_shot(shot_path)
    before = shot.channel("albedo", 1)
    _rewrite_by_rename(shot_path / "albedo" / "000001.exr")
    assert np.array_equal(load_shot(shot_path).channel("albedo", 1), np.full((24, 32, 3), 0.75, np.float32))
    assert np.array_equal(shot.channel("albedo", 1), before)  # cached: what this shot read when it was whole
    shot._cache.clear()  # read again: the file is not the one the shot was opened with
    with pytest.raises(ShotChangedError, match="frame 1"):
        shot.channel("albedo", 1)
