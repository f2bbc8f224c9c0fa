"""Crash recovery: a process SIGKILLed while painting, rendering, saving or autosaving, 24 times at random points;
after every kill a restart finds the last autosave (or is told why not), no project file is ever unreadable, no
render output is half there, and a stale lock is taken over. Then the Qt-free pieces one by one: damaged autosaves
named and set aside, locks held by live and dead processes."""
from __future__ import annotations

import json
import os
import random
import signal
import subprocess
import sys
import time
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from faults_helpers import assert_no_partial_files, edits_digest, tiny_shot_dir

from x2video.edits import Edits, load_project
from x2video.edits.autosave import Autosave, AutosaveError, read_autosave, set_aside, snapshot, write_autosave
from x2video.edits.lock import ProjectLock, ProjectLocked, lock_path

DRIVER = Path(__file__).with_name("crash_driver.py")
MARKERS = {"paint": "begin paint", "render": "rendering", "save": "saving", "autosave": "autosaving"}
KILLS = 24


def _wait_for(journal: Path, start: int, marker: str, server: subprocess.Popen, timeout: float = 60.0) -> bool:
    t0 = time.monotonic()
    while time.monotonic() - t0 < timeout:
        text = journal.read_text()[start:] if journal.exists() else ""
        if any(line.startswith(marker) for line in text.splitlines()):
            return True
        if server.poll() is not None:
            raise AssertionError(f"the driver's server died (exit {server.returncode}): {server.stderr.read().decode()[-2000:]}")
        time.sleep(0.002)
    return False


def _expected(lines: list[str], begin: str, end: str) -> tuple[set[str], bool]:
    """(the digests the file written between `begin D` and `end D` journal lines may hold after the kills, whether
    one write is known to have finished): the last write known finished, and every write begun after it (each
    killed one may or may not have renamed its file in)."""
    may: set[str] = set()
    confirmed = False
    for line in lines:
        if line.startswith(begin + " "):
            may.add(line.split()[1])
        elif line.startswith(end + " ") or (line.startswith("recovered ") and begin == "autosaving" and line != "recovered none"):
            may, confirmed = {line.split()[1]}, True  # written, or found on disk by the restart
        elif line.startswith("aside ") and begin == "autosaving":  # the autosave was set aside: a new one starts
            may, confirmed = set(), False
    return may, confirmed


def _check_restart(work: Path, lines: list[str], outcome: Counter) -> None:
    """What the editor would find on its next start, checked against what the journal says was written."""
    side, project = work / "p.x2v.autosave.json", work / "p.x2v.json"
    may, confirmed = _expected(lines, "autosaving", "autosaved")
    last = next((line for line in reversed(lines) if line.startswith(("autosaving ", "autosaved ", "recovered "))), "")
    if side.exists():
        got = edits_digest(read_autosave(side).current)  # never damaged: an AutosaveError here fails the test
        assert got in may, (got, may, lines[-6:])
        outcome["restored the autosave being written at the kill" if last == f"autosaving {got}" else "restored the last autosave"] += 1
    else:
        assert not confirmed, "an autosave that was written is gone"
        outcome["no autosave written yet"] += 1
    may, confirmed = _expected(lines, "saving", "saved")
    if project.exists():
        assert edits_digest(load_project(project).edits) in may, (may, lines[-6:])  # readable, and what was saved
    else:
        assert not confirmed, "a saved project is gone"
    out = work / "out"
    if out.exists():  # the render's output is all there or not there
        assert sorted(p.name for p in out.iterdir()) == [f"{t:06d}.exr" for t in range(3)]
        assert_no_partial_files(out)
    for staging in work.glob(".out*"):  # a killed render's staging: whole frames (the next render takes them over)
        assert_no_partial_files(staging, temporaries_ok=True)
    for folder in (work, work / "p.x2v.autosave.masks", work / "p.x2v.masks"):
        assert_no_partial_files(folder, temporaries_ok=True, recursive=False)


def test_sigkill_at_random_points_loses_nothing_that_was_autosaved(tmp_path):
    work = tmp_path
    tiny_shot_dir(work / "shot", frames=3, h=16, w=24)
    rng = random.Random(44)
    phases = [p for p in MARKERS for _ in range(KILLS // len(MARKERS))]
    rng.shuffle(phases)
    journal = work / "journal"
    outcome: Counter = Counter()
    killed: Counter = Counter()
    env = {**os.environ, "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"}  # a single-threaded server forks safely
    server = subprocess.Popen([sys.executable, str(DRIVER), "--serve"], env=env, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True)
    try:
        _kill_runs(work, phases, rng, journal, server, outcome, killed)
    finally:
        server.stdin.close()
        server.wait(30)
    print(f"kill points: {dict(killed)}; restarts: {dict(outcome)}")
    assert sum(killed.values()) == KILLS
    assert sum(v for k, v in killed.items() if "not reached" not in k) >= 20
    saved = read_autosave(work / "p.x2v.autosave.json")  # the next autosave clears what killed writes left behind
    write_autosave(work / "p.x2v.autosave.json", saved)
    from x2video.edits import Project, save_project

    save_project(work / "p.x2v.json", Project(shot=str(work / "shot"), edits=saved.current))
    for folder in (work, work / "p.x2v.autosave.masks", work / "p.x2v.masks"):
        assert not [p for p in folder.iterdir() if ".tmp." in p.name], list(folder.iterdir())
    lock = ProjectLock(work / "p.x2v.json")
    assert lock.acquire().startswith("stale")  # the editor's own start takes the last killed run's lock over
    lock.release()
    assert not lock_path(work / "p.x2v.json").exists()


def _kill_runs(work, phases, rng, journal, server, outcome, killed) -> None:
    for k, phase in enumerate(phases):
        if k == KILLS // 2 and (work / "p.x2v.autosave.json").exists():  # one damaged autosave: cut short, as a disk can
            data = (work / "p.x2v.autosave.json").read_bytes()
            (work / "p.x2v.autosave.json").write_bytes(data[: len(data) // 3])
            damaged = True
        else:
            damaged = False
        start = journal.stat().st_size if journal.exists() else 0
        server.stdin.write(f"{work} {k}\n")
        server.stdin.flush()
        pid = int(server.stdout.readline())
        try:
            reached = _wait_for(journal, start, MARKERS[phase], server)
            time.sleep(rng.uniform(0.0, 0.004 if phase == "autosave" else 0.012))
        finally:
            os.kill(pid, signal.SIGKILL)
        status = int(server.stdout.readline().split()[1])
        assert os.WIFSIGNALED(status) and os.WTERMSIG(status) == signal.SIGKILL, status  # killed, not ended by itself
        killed[phase if reached else f"{phase} (not reached: killed anyway)"] += 1
        run = journal.read_text()[start:].splitlines()
        if run:  # (on a starved machine a driver can be killed before its first line: the next one then checks)
            assert run[0].startswith("lock "), (k, phase, reached, run[:3])
            if k:
                assert run[0].startswith("lock stale: pid "), run[0]  # the killed run's lock was taken over
            last = next((line.split()[0] for line in reversed(run) if not line.startswith("begin")), "")
            outcome[f"killed after '{last}'"] += 1
        if damaged and len(run) > 1:
            assert run[1].startswith("aside not readable JSON"), run[1]  # named, set aside, never read again
            assert list(work.glob("p.x2v.autosave.json.corrupt-*")), list(work.iterdir())
            outcome["damaged autosave named and set aside"] += 1
        _check_restart(work, journal.read_text().splitlines(), outcome)


def _autosave(tmp_path: Path) -> Path:
    e = Edits()
    e.add_mask("m")
    e.masks["m"].paint(0, np.eye(8, 10, dtype=np.float32))
    e2 = snapshot(e)
    e2.global_prompt = "after"
    return write_autosave(tmp_path / "p.x2v.autosave.json", Autosave(shot="/s", states=[e, e2], labels=["prompt"], index=1))


@pytest.mark.parametrize("damage", ["truncated", "empty", "not json", "mask file missing", "mask file damaged", "wrong format",
                                    "index out of range"])
def test_a_damaged_autosave_is_named_and_set_aside(damage, tmp_path):
    side = _autosave(tmp_path)
    mask = next((tmp_path / "p.x2v.autosave.masks").iterdir())
    doc = json.loads(side.read_text())
    if damage == "truncated":
        side.write_bytes(side.read_bytes()[:57])
    elif damage == "empty":
        side.write_bytes(b"")
    elif damage == "not json":
        side.write_bytes(b"\x00\xff garbage")
    elif damage == "mask file missing":
        mask.unlink()
    elif damage == "mask file damaged":
        mask.write_bytes(mask.read_bytes()[:20])
    elif damage == "wrong format":
        side.write_text(json.dumps({**doc, "format": "something-else"}))
    else:
        side.write_text(json.dumps({**doc, "index": 7}))
    with pytest.raises(AutosaveError) as info:
        read_autosave(side)
    assert str(side) in str(info.value) and info.value.reason
    aside = set_aside(side)
    assert not side.exists() and aside.exists() and aside.name.startswith("p.x2v.autosave.json.corrupt-")


def test_an_autosave_reads_back_with_its_history_and_masks(tmp_path):
    side = _autosave(tmp_path)
    saved = read_autosave(side)
    assert saved.index == 1 and saved.labels == ["prompt"] and saved.current.global_prompt == "after"
    assert np.array_equal(saved.states[0].masks["m"].frames[0], np.eye(8, 10, dtype=np.float32))
    assert len(list((tmp_path / "p.x2v.autosave.masks").iterdir())) == 1  # both states share the one painted frame


def test_locks_held_by_live_and_dead_processes(tmp_path):
    target = tmp_path / "p.x2v.json"
    other = subprocess.Popen([sys.executable, "-c", "import sys, time; sys.stdout.write('x'); sys.stdout.flush(); time.sleep(30)"],
                             stdout=subprocess.PIPE)
    other.stdout.read(1)
    code = ("import sys; from x2video.edits.lock import ProjectLock; ProjectLock(sys.argv[1]).acquire(); print('held', flush=True); "
            "sys.stdin.read()")
    holder = subprocess.Popen([sys.executable, "-c", code, str(target)], stdin=subprocess.PIPE, stdout=subprocess.PIPE)
    try:
        assert holder.stdout.readline().strip() == b"held"
        with pytest.raises(ProjectLocked) as info:
            ProjectLock(target).acquire()
        assert f"pid {holder.pid}" in str(info.value) and str(target) in str(info.value)
        taken = ProjectLock(target)
        assert taken.acquire(take_over=True).startswith("taken over")  # the person said: open it anyway
        taken.release()
    finally:
        holder.kill()
        holder.wait()
        other.kill()
        other.wait()
    dead = ProjectLock(target)
    lock_path(target).write_text(json.dumps({"pid": other.pid, "host": os.uname().nodename, "since": 0, "token": "x"}))
    assert dead.acquire().startswith("stale")  # its process is gone: taken over without asking
    lock_path(target).write_text("{ not json")
    assert ProjectLock(target).acquire().startswith("stale: the lock file could not be read")
