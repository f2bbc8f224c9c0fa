"""The editor after a crash, offscreen: the last autosave offered back with its undo history and masks, a damaged
autosave named and set aside (the shot still opens), a project open in another editor, a stale lock taken over, and
the start-up offer of an editor that was killed."""
from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest

pytest.importorskip("PySide6")
pytest.importorskip("pytestqt")

import torch  # noqa: E402,F401  (imported here, on the main thread, before any editor worker thread imports it)
from app_helpers import make_shot_dir  # noqa: E402
from PySide6.QtWidgets import QMessageBox  # noqa: E402

from x2video_app._qt.main_window import MainWindow  # noqa: E402

YES, NO = QMessageBox.StandardButton.Yes, QMessageBox.StandardButton.No


@pytest.fixture(scope="module")
def shot(tmp_path_factory):
    return make_shot_dir(tmp_path_factory.mktemp("shots"), frames=3, h=32, w=48)


@pytest.fixture
def window(qtbot, tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    monkeypatch.setenv("X2VIDEO_WEIGHTS", str(tmp_path / "no-weights"))
    made = []

    def make(answer=NO):
        w = MainWindow(bench_dir=tmp_path / "bench", autosave_ms=0, preload=False)
        if hasattr(w, "live"):  # the live preview (another feature) re-renders on every undo step: not what is tested here
            w.live.live_box.setChecked(False)
        w.asked = []
        w.ask = lambda title, text, *a: w.asked.append((title, text)) or answer
        qtbot.addWidget(w)
        made.append(w)
        return w

    yield make
    from superqt.utils import WorkerBase

    for w in made:  # what closing the window does, without its unsaved-changes question
        w.edits.cancel_propagation()
        w.render_ctl.cancel()
        w.render_ctl.wait(30_000)
        if hasattr(w, "live"):  # the live preview's workers (another feature of the window)
            w.live.shutdown()
        w.project.shutdown()
    WorkerBase.await_workers(30_000)
    qtbot.wait(10)


def paint(w, t, box):
    doc = w.doc
    doc.set_frame(t)
    y0, x0, y1, x1 = box
    w.edits.stroke_point(x0, y0, True, 2, False)
    w.edits.stroke_point(x1, y1, False, 2, False)
    w.edits.stroke_end(False)


def test_recovery_gives_back_the_undo_history_and_masks(window, shot):
    w = window()
    assert w.project.open_path(shot), w.errors_shown
    w.edits.add_mask()
    paint(w, 0, (4, 4, 10, 20))
    paint(w, 2, (12, 5, 20, 30))
    w.edits.set_global_prompt("first")
    w.edits.set_global_prompt("second")
    w.act_undo.trigger()  # the person undid one step before the crash: the redo is kept too
    states = []
    for k in range(w.undo.count() + 1):
        w.undo.setIndex(k)
        states.append(w.doc.snapshot())
    w.undo.setIndex(4)
    side = w.project.autosave()
    assert side is not None and side.is_file()

    other = window(answer=YES)  # the next start
    assert other.project.open_path(shot)
    assert [t for t, _ in other.asked] == ["Recover autosaved work?"]
    assert "4 mask" not in other.asked[0][1] and "5 undo step(s)" in other.asked[0][1], other.asked
    assert other.doc.edits == states[4] and other.doc.edits.global_prompt == "first"
    assert other.undo.count() == 5 and other.undo.index() == 4 and other.isWindowModified()
    assert np.array_equal(other.doc.edits.masks["mask 1"].frames[2], states[4].masks["mask 1"].frames[2])
    for k in (3, 2, 1, 0):
        other.act_undo.trigger()
        assert other.doc.edits == states[k], k  # every undo step gives the state it gave before the crash
    other.undo.setIndex(5)
    assert other.doc.edits.global_prompt == "second"  # and the redo


def test_a_saved_project_recovers_to_its_clean_state(window, shot, tmp_path):
    w = window()
    assert w.project.open_path(shot)
    w.edits.set_global_prompt("saved")
    path = tmp_path / "p.x2v.json"
    assert w.project.save_to(path)
    w.edits.set_global_prompt("after saving")
    assert w.project.autosave() is not None
    other = window(answer=YES)
    assert other.project.open_path(path)
    assert other.doc.edits.global_prompt == "after saving" and other.isWindowModified()
    other.act_undo.trigger()
    assert other.doc.edits.global_prompt == "saved" and not other.isWindowModified()  # the project file's state


@pytest.mark.parametrize("damage", [b"", b'{"format": "x2video-autosave", "version": 1, "states": [{"edits"'])
def test_a_damaged_autosave_is_named_set_aside_and_the_shot_opens(window, shot, damage):
    w = window()
    assert w.project.open_path(shot)
    w.edits.set_global_prompt("lost")
    side = w.project.autosave()
    w.project.shutdown()
    side.write_bytes(damage)
    other = window(answer=YES)
    assert other.project.open_path(shot), other.errors_shown
    (title, text), = other.errors_shown
    assert title == "Autosave could not be read" and str(side) in text and "set aside as" in text, text
    assert other.doc.num_frames == 3 and other.doc.edits.global_prompt == "a small test room"  # the shot's caption: no edits
    assert not side.exists() and list(side.parent.glob(side.name + ".corrupt-*"))
    assert other.asked == []  # nothing to offer: it was named, not offered


def test_a_project_open_in_another_editor(window, shot, tmp_path):
    w = window()
    assert w.project.open_path(shot)
    path = tmp_path / "p.x2v.json"
    assert w.project.save_to(path)
    w.project.shutdown()
    code = ("import sys; from x2video.edits.lock import ProjectLock; ProjectLock(sys.argv[1]).acquire(); print('held', flush=True); "
            "sys.stdin.read()")
    holder = subprocess.Popen([sys.executable, "-c", code, str(path)], stdin=subprocess.PIPE, stdout=subprocess.PIPE)
    try:
        assert holder.stdout.readline().strip() == b"held"
        no = window(answer=NO)
        assert not no.project.open_path(path) and no.doc.shot is None
        (title, text), = no.asked
        assert title == "Project open elsewhere" and f"pid {holder.pid}" in text and str(path) in text
        yes = window(answer=YES)
        assert yes.project.open_path(path) and yes.doc.shot is not None  # opened anyway: the lock is taken over
        assert json.loads((tmp_path / "p.x2v.json.lock").read_text())["pid"] == os.getpid()
    finally:
        holder.kill()
        holder.wait()
    w2 = window()
    (tmp_path / "p.x2v.json.lock").write_text(json.dumps({"pid": holder.pid, "host": os.uname().nodename, "since": 0, "token": "t"}))
    assert w2.project.open_path(path) and w2.asked == []  # the holder is gone: a stale lock is taken over silently


def registry_entries() -> list:
    from x2video.edits.autosave import registry_dir

    return sorted(registry_dir().glob("*.json"))


def test_the_next_start_offers_the_work_of_a_killed_editor(window, shot, tmp_path):
    """An editor killed (SIGKILL) with unsaved work: the next start, whatever it was asked to open, offers it."""
    path = tmp_path / "p.x2v.json"
    w = window()
    assert w.project.open_path(shot) and w.project.save_to(path)
    w.project.shutdown()
    code = f"""
import os, signal, sys
from pathlib import Path
from x2video.edits import load_project
from x2video.edits.autosave import Autosave, autosave_path, note_session, snapshot, write_autosave
from x2video.edits.lock import ProjectLock
p = Path({str(path)!r}); side = autosave_path(p, None)
ProjectLock(p).acquire()
e = load_project(p).edits; e2 = snapshot(e); e2.global_prompt = "unsaved when killed"
write_autosave(side, Autosave(shot=load_project(p).shot, project=str(p), states=[e, e2], labels=["prompt"], index=1, clean=0))
os.utime(side, (os.path.getmtime(p) + 5,) * 2)
note_session(side, load_project(p).shot, str(p))
os.kill(os.getpid(), signal.SIGKILL)
"""
    proc = subprocess.run([sys.executable, "-c", code], env={**os.environ})
    assert proc.returncode == -9
    start = window(answer=YES)
    assert start.project.offer_crashed()
    assert start.asked[0][0] == "Recover autosaved work?" and "stopped without saving" in start.asked[0][1]
    assert start.doc.project_path == path and start.doc.edits.global_prompt == "unsaved when killed"
    from x2video.edits.autosave import autosave_path as side_of
    from x2video.edits.autosave import crashed_sessions

    # the recovered work is registered to this editor at once: killed before its first autosave, it is offered again
    entry = json.loads(next(p for p in registry_entries() if json.loads(p.read_text())["autosave"] == str(side_of(path, None).resolve())).read_text())
    assert entry["pid"] == os.getpid() and not any(c.get("autosave") == entry["autosave"] for c in crashed_sessions())
    start.act_undo.trigger()
    assert start.doc.edits.global_prompt == "a small test room" and not start.isWindowModified()  # the saved project's
    assert not window().project.offer_crashed()  # asked once
