"""The real editor SIGKILLed at random points (issue 44): while painting, rendering, saving, autosaving, undoing, or at
a random moment. Each kill point is one editor process (tests/faults/editor_driver.py: `launch` of the main window on
a small shot's project, the editor's own autosave timer shortened by X2VIDEO_AUTOSAVE_MS, a QTimer script doing the
person's work through the window's widgets and actions, a journal of every action and file write). After each kill a
window in this process starts as the next start does and must

- offer the crashed work (`ProjectController.offer_crashed`) whenever what is on disk to restore is an autosave;
- restore exactly the last completed autosave of the journal (or the one being written at the kill): its current
  state, undo index and every undo step's state, masks included; or, where the last write was a save, the project;
- find the project file readable: the last save or the one under way at the kill;
- take over the dead editor's lock;

and the next editor's own start must open what this window found. Nothing is skipped: a kill point whose phase was
not reached in time fails the test.

Each editor is a fresh process (`subprocess.Popen` of editor_driver.py: fork and exec at once), never a fork of a
process that has imported torch or Qt: their threads' locks (OpenMP's and torch's pools, Qt's, logging's) can be held
at the fork and stay held in the child forever, which hung an earlier version of this test. Every wait has a limit:
an editor that writes no journal line for STALL_S (its start included), or does not reach its kill point within
REACH_S, is killed and fails the test with the tails of the journal and of the editors' log; a killed editor not gone
within REAP_S fails it too. STALL_S and REACH_S count the editor's own time, not the time a busy machine kept it
waiting for a CPU (`_wait_for`); the wall clock's bound is pytest's --timeout (pyproject: 600 s), whose failure kills
the editor too (the `finally` of each kill point).
"""
from __future__ import annotations

import os
import random
import signal
import subprocess
import sys
import time
from collections import Counter
from pathlib import Path

import pytest

pytest.importorskip("PySide6")
pytest.importorskip("pytestqt")

import torch  # noqa: E402,F401  (imported here, on the main thread, before any editor worker thread imports it)
from app_helpers import make_shot_dir  # noqa: E402
from faults_helpers import assert_no_partial_files, edits_digest  # noqa: E402
from PySide6.QtWidgets import QMessageBox  # noqa: E402

from x2video.edits import load_project  # noqa: E402
from x2video.edits.autosave import read_autosave  # noqa: E402
from x2video.edits.lock import lock_path, read_lock  # noqa: E402
from x2video_app._qt.main_window import MainWindow  # noqa: E402

DRIVER = Path(__file__).with_name("editor_driver.py")
ROOT = Path(__file__).resolve().parents[2]
#: the journal line each kill point waits for (after a random number of actions), then a short random delay
MARKERS = {"painting": "begin stroke", "rendering": "rendering", "saving": "saving ", "autosaving": "autosaving ",
           "undoing": "begin undo", "anywhere": "begin "}
SEED = 44
AUTOSAVE_MS = 60
YES = QMessageBox.StandardButton.Yes
#: limits (s) of the waits on an editor: no new journal line (its import and start included: ~6 s of CPU), the kill
#: point not reached (both in the editor's own time: `_wait_for`), the killed process not gone (wall clock)
STALL_S, REACH_S, REAP_S = 60.0, 180.0, 30.0


def _env(work: Path) -> dict[str, str]:
    path = os.pathsep.join([str(ROOT), str(ROOT / "core"), str(ROOT / "tests"), os.environ.get("PYTHONPATH", "")])
    return {**os.environ, "PYTHONPATH": path, "QT_QPA_PLATFORM": "offscreen", "XDG_CACHE_HOME": str(work / "cache"),
            "XDG_CONFIG_HOME": str(work / "config"), "X2VIDEO_WEIGHTS": str(work / "no-weights"),
            "X2VIDEO_AUTOSAVE_MS": str(AUTOSAVE_MS), "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1",
            "MKL_NUM_THREADS": "1", "X2VIDEO_TORCH_THREADS": "1"}


def _tails(work: Path, journal: Path, start: int = 0) -> str:
    """The ends of this kill point's journal and of the editors' log, for a failure's message."""
    run = journal.read_text()[start:] if journal.exists() else "(no journal)"
    log = work / "editors.log"
    return f"\n--- journal (this editor) ---\n{run[-3000:]}\n--- editors.log ---\n{log.read_text()[-3000:] if log.exists() else ''}"


def _run_queue_s(pid: int) -> float | None:
    """Seconds the threads of process `pid` have waited, runnable, for a CPU (/proc/PID/task/*/schedstat's 2nd
    field): time a busy machine withheld from them, which is not the editor's (None where there is no schedstat)."""
    total = 0
    try:
        for task in Path(f"/proc/{pid}/task").iterdir():
            try:
                total += int((task / "schedstat").read_text().split()[1])
            except (OSError, IndexError, ValueError):
                pass  # the thread has ended
    except OSError:
        return None
    return total / 1e9


def _wait_for(journal: Path, start: int, marker: str, after: int, proc: subprocess.Popen, work: Path) -> bool:
    """Wait until the run's journal (from byte `start`) has `marker` after its `after`-th action began: False when
    REACH_S passes first; AssertionError when the editor ended by itself or wrote no line for STALL_S.

    Both limits count the editor's own time: the wall clock less what its threads waited on the run queue for a CPU
    (a machine busy with other work, or this test run at nice 19 beside a training job, is not a hang: a deadlocked
    editor sleeps on its lock, off the run queue, and its clock runs at the wall's pace)."""
    now = time.monotonic()
    rq = _run_queue_s(proc.pid)
    mark, own, idle, seen = now, 0.0, 0.0, -1
    while True:
        lines = journal.read_text()[start:].splitlines() if journal.exists() else []
        begun = 0
        for line in lines:
            if begun >= after and line.startswith(marker):
                return True
            begun += line.startswith("begin ")
        if proc.poll() is not None:
            raise AssertionError(f"editor {proc.pid} ended (exit {proc.returncode}) before it was killed"
                                 + _tails(work, journal, start))
        if len(lines) != seen:
            seen, idle = len(lines), 0.0
        now = time.monotonic()
        if now - mark >= 0.25:  # the editor's own time since the last look
            rq_now = _run_queue_s(proc.pid)
            waited = rq_now - rq if rq is not None and rq_now is not None and rq_now >= rq else 0.0
            step = max(0.0, now - mark - waited)
            mark, rq, own, idle = now, rq_now, own + step, idle + step
            if idle > STALL_S:
                raise AssertionError(f"editor {proc.pid} wrote no journal line for {STALL_S:.0f} s of its own time "
                                     f"({'after ' + repr(lines[-1]) if lines else 'none since its start'}): hung"
                                     + _tails(work, journal, start))
            if own > REACH_S:
                return False
        time.sleep(0.003)


def _autosave_key(parts: list[str]) -> tuple:
    """(digest, index, clean, state digests) of an `autosaving` line."""
    digest, index, clean, states = parts
    return ("auto", digest, int(index), None if clean == "None" else int(clean), tuple(states.split(",")))


def _newest(base: tuple, run: list[str]) -> set[tuple]:
    """What the next start may restore after `run` (this kill point's journal), starting from `base`: the newest
    write known to be complete, and the one under way at the kill (it may or may not have renamed its file in)."""
    newest, pending = base, None
    for line in run:
        word, *rest = line.split()
        if word == "autosaving":
            pending = _autosave_key(rest)
        elif word == "saving":
            pending = ("proj", rest[0])
        elif word in ("autosaved", "saved"):
            assert pending is not None and pending[1] == rest[0], (line, pending)
            newest, pending = pending, None
    return {newest} | ({pending} if pending else set())


def _restored(w: MainWindow) -> tuple:
    """What window `w` opened, in `_newest`'s terms (the undo stack walked: every state's digest)."""
    undo, digest = w.undo, edits_digest(w.doc.edits)
    if undo.count() == 0 and not w.isWindowModified():
        return ("proj", digest)
    index, states = undo.index(), []
    for k in range(undo.count() + 1):
        undo.setIndex(k)
        states.append(edits_digest(w.doc.edits))
    undo.setIndex(index)
    assert edits_digest(w.doc.edits) == digest
    clean = undo.cleanIndex()
    return ("auto", digest, index, None if clean < 0 or w.project.force_dirty else clean, tuple(states))


def _on_disk(project: Path, side: Path) -> tuple:
    """What a start finds: the autosave when it is newer than the project file (the editor's rule), else the project."""
    if side.exists() and side.stat().st_mtime > project.stat().st_mtime:
        a = read_autosave(side)
        return ("auto", edits_digest(a.current), a.index, a.clean, tuple(edits_digest(s) for s in a.states))
    return ("proj", edits_digest(load_project(project).edits))


@pytest.fixture
def window(qtbot):
    made = []

    def make() -> MainWindow:
        w = MainWindow(bench_dir=Path(os.environ["XDG_CACHE_HOME"]) / "bench", autosave_ms=0, preload=False)
        w.live.live_box.setChecked(False)  # the live preview re-renders on every undo step: not what is tested here
        w.asked = []
        w.ask = lambda title, text, *a: w.asked.append((title, text)) or YES
        qtbot.addWidget(w)
        made.append(w)
        return w

    def close(w: MainWindow) -> None:  # what closing the window does, without its unsaved-changes question
        w.edits.cancel_propagation()
        w.render_ctl.cancel()
        w.render_ctl.wait(30_000)
        w.live.shutdown()
        w.project.shutdown()

    make.close = close
    yield make
    from superqt.utils import WorkerBase

    WorkerBase.await_workers(30_000)
    qtbot.wait(10)


def test_the_real_editor_sigkilled_at_random_points_gives_back_its_last_autosave(window, tmp_path, monkeypatch):
    work = tmp_path
    for k, v in _env(work).items():
        if k.startswith("X") and k != "X2VIDEO_AUTOSAVE_MS":
            monkeypatch.setenv(k, v)  # this process's windows share the cache (the session registry) with the editors
    shot = make_shot_dir(work / "shots", frames=3, h=32, w=48)
    project, side = work / "p.x2v.json", work / "p.x2v.autosave.json"
    first = window()
    assert first.project.open_path(shot) and first.project.save_to(project), first.errors_shown
    window.close(first)
    base = (_on_disk(project, side), edits_digest(load_project(project).edits))
    rng = random.Random(SEED)
    phases = list(MARKERS)
    rng.shuffle(phases)
    journal = work / "journal"
    killed: Counter = Counter()
    outcome: Counter = Counter()
    t0, cpu0 = time.monotonic(), os.times()
    with open(work / "editors.log", "w") as log:
        try:
            for k, phase in enumerate(phases):
                base = _kill_and_restart(k, phase, base, rng, work, journal, log, window, killed, outcome)
        except BaseException:
            print(_tails(work, journal))
            raise
    cpu = os.times()
    print(f"kill points: {dict(killed)}; restarts: {dict(outcome)}; {time.monotonic() - t0:.1f} s wall, "
          f"{cpu.children_user + cpu.children_system - cpu0.children_user - cpu0.children_system:.1f} s CPU in the editors")
    assert sum(killed.values()) == len(MARKERS) >= 5


def _kill_and_restart(k, phase, base, rng, work, journal, log, window, killed, outcome) -> tuple:
    """One kill point; `base`: what a start found on disk before it (`_on_disk`, the project file's digest)."""
    base, saved = base
    project, side = work / "p.x2v.json", work / "p.x2v.autosave.json"
    start = journal.stat().st_size if journal.exists() else 0
    log.write(f"=== kill point {k} ({phase}) ===\n")
    log.flush()
    # a fresh interpreter (fork and exec at once), never a fork of a threaded process; its own session, so that the
    # kill reaches anything it started too
    proc = subprocess.Popen([sys.executable, str(DRIVER), str(work), str(SEED * 100 + k)], env=_env(work),
                            stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT, cwd=ROOT,
                            start_new_session=True)
    pid = proc.pid
    try:
        reached = _wait_for(journal, start, MARKERS[phase], rng.randint(3, 14), proc, work)
        time.sleep(rng.uniform(0.0, 0.25 if phase == "anywhere" else 0.01))
    finally:
        try:
            os.killpg(pid, signal.SIGKILL)
        except ProcessLookupError:
            pass  # ended already: `_wait_for` said so
        try:
            proc.wait(REAP_S)
        except subprocess.TimeoutExpired:
            raise AssertionError(f"editor {pid} still there {REAP_S:.0f} s after its SIGKILL") from None
    assert proc.returncode == -signal.SIGKILL, proc.returncode  # killed, not ended by itself
    run = journal.read_text()[start:].splitlines()
    assert reached, f"kill point {k}: '{MARKERS[phase]}' not reached in {REACH_S:.0f} s" + _tails(work, journal, start)
    killed[phase] += 1
    opened = [line for line in run if line.startswith(("opened ", "begin "))][0]
    assert run[0] == f"start {pid}" and opened.startswith("opened "), run[:3]
    # the editor's own start (launch: offer_crashed, then the project and its newer autosave) opened what the last
    # window here found on disk
    assert opened.split()[1] == base[1], (opened, base)
    last = next((line.split()[0] for line in reversed(run) if not line.startswith(("begin", "end"))), "")
    outcome[f"killed after '{last}'"] += 1

    may = _newest(base, run)
    assert edits_digest(load_project(project).edits) in _saves(saved, run)  # readable: the last save, or the one under way
    on_disk = _on_disk(project, side)  # never a damaged autosave: AutosaveError here fails the test
    assert on_disk in may, (on_disk, may, run[-8:])
    for folder in (work, work / "p.x2v.autosave.masks", work / "p.x2v.masks"):
        assert_no_partial_files(folder, temporaries_ok=True, recursive=False)
    held = read_lock(lock_path(project))
    assert held is not None and held.pid == pid, held  # the dead editor's lock is still there

    w = window()
    offered = w.project.offer_crashed()
    if on_disk[0] == "auto":
        assert offered, f"the start did not offer the autosave of the killed editor: {run[-8:]}"
        assert w.asked and w.asked[0][0] == "Recover autosaved work?" and "stopped without saving" in w.asked[0][1], w.asked
    if not offered:
        assert w.project.open_path(project), w.errors_shown
    assert w.doc.project_path == project and not w.errors_shown, w.errors_shown
    got = _restored(w)
    assert got == on_disk, (got, on_disk)  # the current state, the undo index, every undo step (masks included)
    outcome["restored the autosave" if got[0] == "auto" else "opened the project as saved"] += 1
    if len(may) > 1:
        outcome["the write under way at the kill: " + ("it" if got != base and got in may - {base} else "the one before")] += 1
    now = read_lock(lock_path(project))
    assert w.project.lock is not None and w.project.lock.held and now.pid == os.getpid(), now  # taken over
    window.close(w)
    return _on_disk(project, side), edits_digest(load_project(project).edits)


def _saves(saved: str, run: list[str]) -> set[str]:
    """Digests the project file may hold: the last save known complete (`saved`: before `run`), and one under way."""
    out = {saved}
    for line in run:
        if line.startswith("saving "):
            out.add(line.split()[1])
        elif line.startswith("saved "):
            out = {line.split()[1]}
    return out
