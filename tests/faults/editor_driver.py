"""The real editor, driven by a script inside its own process, for the SIGKILL test of the editor
(tests/faults/test_app_sigkill.py), which kills it at random points.

    python editor_driver.py WORK SEED    one editor on WORK/p.x2v.json, its script seeded by SEED

The test starts one such process per kill point (`subprocess.Popen`: fork and exec at once, a fresh interpreter that
imports torch, PySide6 and x2video_app itself, several seconds of CPU each). It is never forked from a process that
has already imported them: such a process runs threads (torch's and OpenMP's pools, Qt's, logging's locks) and a
fork copies only the forking thread, so a lock another thread held at the fork stays held in the child forever (an
earlier server that forked its editors hung so: an editor that never wrote a journal line).

Each editor starts the way a person does: `x2video_app._qt.launch.launch([WORK/p.x2v.json])` (the window,
then on the event loop `offer_crashed()` and opening the project, whose autosave, when newer, is offered) with the
editor's own autosave timer every X2VIDEO_AUTOSAVE_MS (set by the test). Every question the editor asks is answered
Yes (recover the autosave, render with the untrained model); the model is a stand-in (`sampling_fake.FakeModel`,
nothing is built: the render is the formula tier, which uses no network). Then a QTimer script performs, every tick,
one step of a seeded random list of editor actions, through the window's own widgets, signals and actions: a paint
stroke (the viewer's press, move and release signals, one per tick, so a kill can land mid-stroke), a new mask, the
global prompt (Scene panel), the exposure slider (Parametric edits), Undo, Redo, Save (File menu: the project file)
and Render (Render menu, quality "formula").

Before and after each action, and around the editor's own file writes (its module's `write_autosave`,
`note_session` and `save_project`, wrapped), it appends a line to WORK/journal (an O_APPEND write: a SIGKILL cannot
lose a line that was written):

    start <pid>                                           the process runs
    opened <digest> <undo index> <undo count>             launch's start opened the project (recovered or not)
    begin <stroke|mask|prompt|param|undo|redo|save|render> <step> / end <action> <step> <digest>
    autosaving <digest> <index> <clean> <d0,d1,...>       the editor's autosave writes these undo states
    autosaved <digest>                                    ... and has written them
    noting / noted                                        around the registry entry of the session (note_session)
    saving <digest> / saved <digest>                      around the project file's write
    rendering / rendered <status>                         a render started / ended
"""
from __future__ import annotations

import os
import random
import sys
import traceback
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tests/: sampling_fake

import torch  # noqa: E402,F401  (before the editor's worker threads could import it)
from faults_helpers import edits_digest  # noqa: E402
from sampling_fake import FakeModel  # noqa: E402

import x2video_app._qt.project_controller as pc  # noqa: E402
from x2video.render.renderer import Renderer  # noqa: E402
from x2video_app._qt.launch import launch  # noqa: E402

ACTIONS = ["stroke", "stroke", "stroke", "mask", "prompt", "param", "undo", "undo", "redo", "save", "render"]
TICK_MS = 15


def drive(work: Path, seed: int) -> None:
    from PySide6.QtCore import QTimer
    from PySide6.QtWidgets import QMessageBox

    fd = os.open(work / "journal", os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)

    def journal(line: str) -> None:
        os.write(fd, (line + "\n").encode())

    journal(f"start {os.getpid()}")
    write_autosave, note_session, save_project = pc.write_autosave, pc.note_session, pc.save_project

    def autosave_journaled(path, autosave, **kw):
        digests = ",".join(edits_digest(s) for s in autosave.states)
        journal(f"autosaving {edits_digest(autosave.current)} {autosave.index} {autosave.clean} {digests}")
        out = write_autosave(path, autosave, **kw)
        journal(f"autosaved {edits_digest(autosave.current)}")
        return out

    def note_journaled(*a, **kw):
        journal("noting")
        note_session(*a, **kw)
        journal("noted")

    def save_journaled(path, project):
        journal(f"saving {edits_digest(project.edits)}")
        save_project(path, project)
        journal(f"saved {edits_digest(project.edits)}")

    pc.write_autosave, pc.note_session, pc.save_project = autosave_journaled, note_journaled, save_journaled

    app, win = launch([str(work / "p.x2v.json")])
    win.ask = lambda title, text, buttons, default: QMessageBox.StandardButton.Yes  # a person who says yes to all
    win.render_ctl.renderer_factory = lambda choice: Renderer(FakeModel())  # no weights here; the formula needs none
    win.render_panel.quality.setCurrentIndex(win.render_panel.quality.findData("formula"))
    rng = random.Random(seed)
    state = {"step": 0, "opened": False, "stroke": None}
    win.render_ctl.sigRunning.connect(lambda running: None if running else journal(f"rendered {win.doc.render.status}"))

    def tick() -> None:
        if not state["opened"]:
            if win.doc.shot is None:
                return
            state["opened"] = True
            journal(f"opened {edits_digest(win.doc.edits)} {win.undo.index()} {win.undo.count()}")
            return
        v = win.viewer
        if state["stroke"] is not None:  # a stroke in progress: one move or the release per tick
            step, points = state["stroke"]
            if points:
                x, y = points.pop(0)
                v.sigStrokePoint.emit(x, y, False)
            else:
                v.sigStrokeEnd.emit()
                state["stroke"] = None
                journal(f"end stroke {step} {edits_digest(win.doc.edits)}")
            return
        step = state["step"]
        state["step"] += 1
        action = rng.choice(ACTIONS)
        journal(f"begin {action} {step}")
        h, w = win.doc.size
        if action == "stroke":
            win.timeline.sigFrame.emit(rng.randrange(win.doc.num_frames))
            if win.doc.selected_mask < 0 and win.doc.edits.masks:
                win.mask_panel.sigSelect.emit(0)
            x, y = rng.uniform(0, w), rng.uniform(0, h)
            v.sigStrokePoint.emit(x, y, True)
            state["stroke"] = (step, [(rng.uniform(0, w), rng.uniform(0, h)) for _ in range(rng.randint(1, 3))])
            return  # `end stroke` when released
        if action == "mask":
            win.mask_panel.sigAdd.emit()
        elif action == "prompt":
            win.scene_panel.sigGlobalPrompt.emit(f"prompt {step}")
        elif action == "param":
            win.edit_panel.exposure.setValue(round(rng.uniform(-2, 2), 2))
        elif action == "undo":
            win.act_undo.trigger()
        elif action == "redo":
            win.act_redo.trigger()
        elif action == "save":
            win.act_save.trigger()
        elif action == "render":
            if win.act_render.isEnabled() and win.start_render():
                journal("rendering")
        journal(f"end {action} {step} {edits_digest(win.doc.edits)}")

    timer = QTimer()
    timer.timeout.connect(tick)
    timer.start(TICK_MS)
    app.exec()


def main(argv: list[str]) -> None:
    work, seed = argv
    status = 0
    try:
        drive(Path(work), int(seed))
    except BaseException:
        traceback.print_exc()  # into the test's editors.log
        status = 1
    finally:
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(status)  # no interpreter shutdown (torch's and Qt's exit handlers); the test kills it before this


if __name__ == "__main__":
    main(sys.argv[1:])
