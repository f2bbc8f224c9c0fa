"""A headless stand-in for the editor that the SIGKILL test kills at random points (tests/faults/test_fault_crash.py).

    python crash_driver.py WORK SEED      (or --serve: forks one per line "WORK SEED" on stdin)

It drives the editor's Qt-free save paths on WORK/shot: it takes the project's lock (`x2video.edits.lock`), recovers
what the last autosave holds (`x2video.edits.autosave`, as the editor does on start), then forever: paints mask
frames, changes prompts, adds masks, undoes and redoes, autosaves the undo history after every step, saves the
project now and then (`save_project`) and renders the formula into WORK/out through `FrameSink` (resumable). Before
and after each file operation it appends a line to WORK/journal (an O_APPEND write: a SIGKILL cannot lose a line
that was written), so the test knows what each file must hold after the kill:

    lock <how>                                  the lock was taken (new / stale: ... / own)
    recovered <digest> <index> <states> | none | aside <reason>
    begin <paint|param|mask|undo|redo|save|render> <step>
    autosaving <digest>  / autosaved <digest>   around write_autosave
    saving <digest>      / saved <digest>       around save_project
    rendering            / rendered             around the render
"""
from __future__ import annotations

import os
import random
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from faults_helpers import edits_digest  # noqa: E402

from x2video.conditioning.edited import apply_edits
from x2video.edits import Edits, Project, load_project, save_project  # noqa: E402
from x2video.edits.autosave import Autosave, AutosaveError, autosave_path, read_autosave, set_aside, snapshot, write_autosave  # noqa: E402
from x2video.edits.lock import ProjectLock  # noqa: E402
from x2video.io import load_shot  # noqa: E402
from x2video.render.frames import FrameSink, resume_key  # noqa: E402

KEEP = 12


def serve() -> None:
    """`--serve`: fork one driver per line `WORK SEED` read from stdin (the imports are paid once; each driver is a
    real process of its own, killed for real); answer `PID` when it runs and `exit STATUS` when it is gone."""
    for line in sys.stdin:
        work, seed = line.split()
        pid = os.fork()
        if pid == 0:
            try:
                drive(Path(work), int(seed))
            finally:
                os._exit(0)
        print(pid, flush=True)
        _, status = os.waitpid(pid, 0)
        print(f"exit {status}", flush=True)


def drive(work: Path, seed: int) -> None:
    fd = os.open(work / "journal", os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)

    def journal(line: str) -> None:
        os.write(fd, (line + "\n").encode())

    project = work / "p.x2v.json"
    side = autosave_path(project, None)  # where the editor autosaves a project: p.x2v.autosave.json
    shot = load_shot(work / "shot")
    journal(f"lock {ProjectLock(project).acquire()}")
    states, labels, index = [Edits()], [], 0
    try:
        saved = read_autosave(side) if side.exists() else None
    except AutosaveError as exc:
        journal(f"aside {exc.reason.splitlines()[0]} -> {set_aside(side).name}")
        saved = None
    if saved is not None:
        states, labels, index = saved.states, saved.labels, saved.index
        journal(f"recovered {edits_digest(saved.current)} {index} {len(states)}")
    elif project.exists():
        states = [load_project(project).edits]
        journal("recovered none")
    else:
        journal("recovered none")
    rng = random.Random(seed)
    h, w = shot.size
    for step in range(10**6):
        action = rng.choice(["paint", "paint", "paint", "param", "mask", "undo", "redo", "save", "render"])
        journal(f"begin {action} {step}")
        cur = states[index]
        if action in ("paint", "param", "mask"):
            e = snapshot(cur)
            if action == "mask" or not e.masks:
                e.add_mask(f"m{step}")
            if action == "param":
                e.global_prompt = f"prompt {step}"
            else:
                name = rng.choice(sorted(e.masks))
                t = rng.randrange(shot.num_frames)
                a = e.masks[name].painted(t, (h, w))
                y, x = rng.randrange(h - 4), rng.randrange(w - 4)
                a[y:y + 4, x:x + 4] = 1.0
                e.masks[name].paint(t, a)
            del states[index + 1:], labels[index:]
            states.append(e)
            labels.append(f"{action} {step}")
            index += 1
            if len(states) > KEEP:  # a short history keeps each autosave cheap (the editor keeps `MAX_STATES`)
                del states[:-KEEP], labels[:-(KEEP - 1)]
                index = len(states) - 1
        elif action == "undo" and index > 0:
            index -= 1
        elif action == "redo" and index + 1 < len(states):
            index += 1
        elif action == "save":
            journal(f"saving {edits_digest(cur)}")
            save_project(project, Project(shot=str(work / "shot"), edits=cur))
            journal(f"saved {edits_digest(cur)}")
        elif action == "render":
            journal("rendering")
            key = resume_key(edits=edits_digest(cur))
            with FrameSink(work / "out", expected=list(range(shot.num_frames)), resume=key) as sink:
                for t in range(shot.num_frames):
                    c = apply_edits(shot, cur, t).channels
                    rgb = c["albedo"] * c["irradiance"]
                    sink.add(t, np.asarray(rgb, np.float32))
                sink.finish()
            journal("rendered")
        journal(f"autosaving {edits_digest(states[index])}")
        write_autosave(side, Autosave(shot=str(work / "shot"), project=str(project), states=states, labels=labels, index=index))
        journal(f"autosaved {edits_digest(states[index])}")


if __name__ == "__main__":
    if sys.argv[1] == "--serve":
        serve()
    else:
        drive(Path(sys.argv[1]), int(sys.argv[2]))
