"""`x2video farm`: jobs from folders and list files, done markers and resume, Open Job Description templates, and
renders on a local Ray cluster of 2 workers: the farm's frames equal `x2video render`'s in one process (same seed,
bit for bit: both run torch on one thread), and a worker killed mid-render is retried while nothing finished is
rendered again."""
from __future__ import annotations

import contextlib
import json
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Callable, Iterator

import numpy as np
import pytest

from x2video.cli import main
from x2video.farm import find_jobs, run_farm, state
from x2video.farm.openjd import SPECIFICATION, write_templates
from x2video.fields import to_flags
from x2video.io import write_shot_folder
from x2video.render.settings import RenderSettings
from x2video.shot import ArrayShot
from x2video.weights import ModelOptions

H, W = 32, 48


def make_shot(path: Path, frames: int, seed: int, size: tuple[int, int] = (H, W)) -> Path:
    H, W = size
    rng = np.random.default_rng(seed)
    n = np.zeros((frames, H, W, 3), np.float32)
    n[..., 2] = 1
    albedo = (0.2 + 0.6 * rng.random((1, H, W, 3))).repeat(frames, 0).astype(np.float32)
    irr = (0.5 + 0.5 * rng.random((frames, H, W, 3))).astype(np.float32)
    s = ArrayShot({"albedo": albedo, "normal": n, "roughness": np.full((frames, H, W, 1), 0.5, np.float32),
                   "metallic": np.zeros((frames, H, W, 1), np.float32), "irradiance": irr}, fps=8.0)
    return write_shot_folder(s, path)


def frames_of(folder: Path) -> dict[str, np.ndarray]:
    from x2video.io.image import read_image

    images = {p.name: read_image(p) for p in sorted(folder.glob("*.exr"))}
    return {name: np.stack([im.planes[c] for c in im.channel_names], -1) for name, im in images.items()}


def assert_same_frames(a: Path, b: Path) -> None:
    fa, fb = frames_of(a), frames_of(b)
    assert fa and sorted(fa) == sorted(fb), (sorted(fa), sorted(fb))
    for name in fa:
        np.testing.assert_array_equal(fa[name], fb[name], err_msg=f"{a / name} vs {b / name}")


# --- jobs, markers, templates: no Ray -------------------------------------------------------------------


def test_jobs_from_a_folder_a_list_file_and_a_project(tmp_path):
    from x2video.edits import Edits, Project, save_project

    shots = tmp_path / "shots"
    a, b = make_shot(shots / "a", 3, 0), make_shot(shots / "b", 3, 1)
    (shots / "notes").mkdir()  # neither shot nor project: ignored in a folder of shots
    save_project(tmp_path / "dusk.x2v.json", Project(shot=str(a), edits=Edits(global_prompt="dusk")))
    assert [(j.name, j.kind) for j in find_jobs([shots])] == [("a", "shot"), ("b", "shot")]
    listing = tmp_path / "list.txt"
    listing.write_text("# nightly\nshots/b\n\ndusk.x2v.json  # the graded one\n")
    jobs = find_jobs([listing])
    assert [(j.name, j.kind, j.source) for j in jobs] == [("b", "shot", b.resolve()), ("dusk", "project", (tmp_path / "dusk.x2v.json").resolve())]
    assert [j.name for j in find_jobs([a])] == ["a"]  # a shot itself is one job


def test_job_errors_name_the_file_and_line(tmp_path):
    make_shot(tmp_path / "x" / "a", 2, 0)
    make_shot(tmp_path / "y" / "a", 2, 0)
    with pytest.raises(ValueError, match="two jobs would write the output 'a'"):
        find_jobs([tmp_path / "x", tmp_path / "y"])
    listing = tmp_path / "list.txt"
    listing.write_text("x/a\nnope\n")
    with pytest.raises(FileNotFoundError, match=r"list.txt, line 2"):
        find_jobs([listing])
    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError, match="neither a shot nor a folder"):
        find_jobs([tmp_path / "empty"])


def test_to_flags_round_trips_through_the_parser():
    import argparse

    from x2video.fields import add_fields, from_args

    s = RenderSettings(seed=3, seams=False, frames=(2, 7), exposure=1.5, preset="fast", noise_shared=0.5, quality="formula")
    flags = to_flags(RenderSettings, s)
    assert "--no-seams" in flags and flags[flags.index("--frames") + 1] == "2:7" and "--steps" not in flags
    p = argparse.ArgumentParser()
    add_fields(p, RenderSettings)
    assert from_args(RenderSettings, p.parse_args(flags)) == s
    assert from_args(RenderSettings, p.parse_args(to_flags(RenderSettings, s, only_changed=False))) == s


def test_marker_with_other_settings_is_an_error_not_a_silent_rerender(tmp_path):
    job = find_jobs([make_shot(tmp_path / "a", 2, 0)])[0]
    out = tmp_path / "out"
    (out / "a").mkdir(parents=True)
    key = state.job_key(job, RenderSettings(seed=1), ModelOptions(), "exr", None)
    state.write_marker(out, job, key, out / "a", 2, 1.0, 1)
    assert state.finished(out, job, key)["frames"] == 2
    with pytest.raises(ValueError, match=r"a.done.json: this shot was rendered with other settings.seed"):
        state.finished(out, job, state.job_key(job, RenderSettings(seed=2), ModelOptions(), "exr", None))
    shutil.rmtree(out / "a")  # output removed by hand: to render again
    assert state.finished(out, job, key) is None


def test_openjd_templates_validate_with_openjd_model(tmp_path):
    openjd_model = pytest.importorskip("openjd.model")
    from x2video.edits import Edits, Project, save_project

    a = make_shot(tmp_path / "shots" / "a", 3, 0)
    save_project(tmp_path / "shots" / "dusk.x2v.json", Project(shot=str(a), edits=Edits(global_prompt="dusk")))
    settings = RenderSettings(preset="fast", seed=4, seams=False)
    paths = write_templates(find_jobs([tmp_path / "shots"]), tmp_path / "jobs", tmp_path / "out", settings, ModelOptions(untrained=True), "mp4", 12.0)
    assert [p.name for p in paths] == ["a.template.json", "dusk.template.json"]
    for path in paths:
        doc = json.loads(path.read_text())
        assert doc["specificationVersion"] == SPECIFICATION
        template = openjd_model.decode_job_template(template=doc)
        values = openjd_model.preprocess_job_parameters(job_template=template, job_parameter_values=json.loads(path.with_name(
            path.name.replace(".template.", ".params.")).read_text()), job_template_dir=path.parent, current_working_dir=tmp_path)
        job = openjd_model.create_job(job_template=template, job_parameter_values=values)
        assert [s.name for s in job.steps] == ["Render"]
        args = doc["steps"][0]["script"]["actions"]["onRun"]["args"]
        assert args[:1] == ["render"] and "--untrained" in args and "--no-seams" in args and args[args.index("--seed") + 1] == "4"
        assert args[args.index("--fps") + 1] == "12.0"
    dusk = json.loads(paths[1].read_text())
    assert dusk["steps"][0]["script"]["actions"]["onRun"]["args"][1:3] == ["--project", "{{Param.Project}}"]
    assert json.loads((tmp_path / "jobs" / "dusk.params.json").read_text())["Output"] == str((tmp_path / "out" / "dusk.mp4").resolve())


def test_openjd_cli_runs_a_template_here(tmp_path):
    """`openjd run` executes the template's step on this machine: the formula render lands where the template says."""
    openjd = Path(sys.executable).with_name("openjd")
    x2video = Path(sys.executable).with_name("x2video")
    if not openjd.is_file() or not x2video.is_file():
        pytest.skip("openjd-cli or the x2video launcher is not installed beside this Python")
    job = find_jobs([make_shot(tmp_path / "a", 3, 0)])[0]
    out = tmp_path / "out"
    [path] = write_templates([job], tmp_path / "jobs", out, RenderSettings(quality="formula"), ModelOptions())
    p = subprocess.run([str(openjd), "run", str(path), "--step", "Render", "-p", f"file://{path.parent / 'a.params.json'}",
                        "-p", f"X2Video={x2video}"], capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stdout[-3000:] + p.stderr[-3000:]
    assert sorted(f.name for f in (out / "a").iterdir()) == ["000000.exr", "000001.exr", "000002.exr"]


def test_farm_openjd_flag_writes_templates_without_ray(tmp_path, capsys):
    make_shot(tmp_path / "shots" / "a", 2, 0)
    assert main(["farm", str(tmp_path / "shots"), "--out", str(tmp_path / "out"), "--openjd", str(tmp_path / "jobs"), "--seed", "9"]) == 0
    doc = json.loads((tmp_path / "jobs" / "a.template.json").read_text())
    assert doc["steps"][0]["script"]["actions"]["onRun"]["args"][-2:] == ["--seed", "9"]
    assert "wrote 1 Open Job Description template" in capsys.readouterr().out


# --- on a local Ray cluster of 2 workers ----------------------------------------------------------------------

@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    """A local Ray cluster with 2 CPUs (2 worker processes at a time), a small object store, no dashboard."""
    ray = pytest.importorskip("ray")
    ray.init(num_cpus=2, object_store_memory=80 * 1024**2, include_dashboard=False, log_to_driver=False,
             _temp_dir=str(tmp_path_factory.mktemp("ray")))
    yield
    ray.shutdown()


FAST = ["--preset", "fast", "--quality", "diffusion", "--seed", "5"]


@pytest.fixture(scope="module")
def shots(tmp_path_factory):
    """Three tiny shots (the last one longer: it is the one whose worker gets killed) and their single-process renders."""
    import torch

    root = tmp_path_factory.mktemp("farm")
    shots = [make_shot(root / "shots" / n, f, i) for i, (n, f) in enumerate([("a", 5), ("b", 9), ("c", 17)])]
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # as a farm task with 1 CPU: same thread count, same floating-point sums
    try:
        for s in shots:
            assert main(["render", str(s), "--out", str(root / "ref" / s.name), *FAST]) == 0
    finally:
        torch.set_num_threads(threads)
    return root


def _settings() -> RenderSettings:
    return RenderSettings(preset="fast", quality="diffusion", seed=5)


@pytest.mark.slow
@pytest.mark.timeout(900)
@contextlib.contextmanager
def kill_when(victim: Callable[[], dict | None], interval: float) -> Iterator[dict]:
    """While the body runs, a thread polls `victim` every `interval` seconds; the first record it returns (a task's
    status, with the worker's 'pid') is SIGKILLed, once, and copied into the dict this yields."""
    killed: dict = {}
    stop = threading.Event()

    def loop() -> None:
        while not stop.is_set():
            rec = victim()
            if rec:
                killed.update(rec)
                os.kill(rec["pid"], signal.SIGKILL)
                return
            time.sleep(interval)

    thread = threading.Thread(target=loop, daemon=True)
    thread.start()
    try:
        yield killed
    finally:
        stop.set()
        thread.join(5)


def test_farm_frames_equal_a_single_process_render(cluster, shots, tmp_path):
    out = tmp_path / "out"
    lines: list[str] = []
    result = run_farm(find_jobs([shots / "shots"]), out, _settings(), ModelOptions(), write=lines.append, poll_seconds=0.1)
    assert result.ok and sorted(result.done) == ["a", "b", "c"], (result.failed, lines)
    for name in "abc":
        assert_same_frames(shots / "ref" / name, out / name)
        assert json.loads((out / f"{name}.done.json").read_text())["frames"] == {"a": 5, "b": 9, "c": 17}[name]
    assert any(line.startswith("farm c  running:") and "frames" in line for line in lines), lines  # progress per shot
    assert not list(out.glob(".*partial"))


@pytest.mark.slow
@pytest.mark.timeout(900)
def test_killed_worker_is_retried_and_nothing_finished_is_redone(cluster, shots, tmp_path):
    """One task per shot (--no-split): the shot whose worker is killed starts over, the others are not touched."""
    out = tmp_path / "out"
    finished_at_kill: dict[str, tuple] = {}

    def victim() -> dict | None:  # the worker that renders c once its keyframes exist (mid-render)
        s = state.read_status(out, "c")
        if s.get("state") == "running" and (s.get("frames_done") or 0) > 0:
            for name in "ab":
                m = state.marker_path(out, name)
                if m.exists():
                    finished_at_kill[name] = (m.stat().st_mtime_ns, m.read_bytes())
            return s
        return None

    with kill_when(victim, 0.02) as killed:
        result = run_farm(find_jobs([shots / "shots"]), out, _settings(), ModelOptions(), retries=2, split=False, write=lambda s: None,
                          poll_seconds=0.1)
    assert killed, "the killer never saw shot c running with frames"
    assert 0 < killed["frames_done"] < 17
    assert result.ok and sorted(result.done) == ["a", "b", "c"], result.failed
    starts = {n: state.read_status(out, n)["starts"] for n in "abc"}
    assert [s["attempt"] for s in starts["c"]] == [1, 2] and starts["c"][0]["pid"] == killed["pid"] != starts["c"][1]["pid"]
    assert len(starts["a"]) == len(starts["b"]) == 1  # nothing finished was rendered again
    assert json.loads((out / "c.done.json").read_text())["attempt"] == 2
    for name, (mtime, data) in finished_at_kill.items():
        m = state.marker_path(out, name)
        assert (m.stat().st_mtime_ns, m.read_bytes()) == (mtime, data)
    for name in "abc":
        assert_same_frames(shots / "ref" / name, out / name)
    assert not list(out.glob(".*partial")), "the killed attempt's staging folder was left behind"

    # resume: the same command again renders nothing and starts nothing
    again = run_farm(find_jobs([shots / "shots"]), out, _settings(), ModelOptions(), split=False, write=lambda s: None)
    assert sorted(again.skipped) == ["a", "b", "c"] and not again.done
    assert {n: state.read_status(out, n)["starts"] for n in "abc"} == starts


@pytest.mark.timeout(600)
def test_cli_farm_formula_resume_and_status(cluster, tmp_path, capsys):
    """`x2video farm` end to end (formula tier: no weights): progress lines, a second run skips, --status reads OUT."""
    shots = tmp_path / "shots"
    make_shot(shots / "a", 3, 0)
    make_shot(shots / "b", 4, 1)
    out = tmp_path / "out"
    assert main(["farm", str(shots), "--out", str(out), "--quality", "formula", "--chunk-frames", "2"]) == 0
    text = capsys.readouterr().out
    assert "farm a  done: 3 frames" in text and "farm b  done: 4 frames" in text and "2 rendered, 0 finished before, 0 failed" in text
    assert "(attempt 1, 2 chunks)" in text
    assert main(["render", str(shots / "b"), "--out", str(tmp_path / "ref_b"), "--quality", "formula"]) == 0
    assert_same_frames(tmp_path / "ref_b", out / "b")
    assert main(["farm", str(shots), "--out", str(out), "--quality", "formula"]) == 0
    assert "0 rendered, 2 finished before" in capsys.readouterr().out
    assert main(["farm", str(shots), "--out", str(out), "--quality", "formula", "--seed", "3"]) == 2  # other settings: refused
    assert "rendered with other settings.seed" in capsys.readouterr().err
    assert main(["farm", "--out", str(out), "--status"]) == 0
    assert "a: done, 3 frames" in capsys.readouterr().out


# --- one shot split into frame chunks (tiers 0 and 1) --------------------------------------------------------

AUTO = ["--quality", "auto", "--seed", "5"]  # the shipped weights: tier 1 for a shot with every channel


def _one_thread_render(shot: Path, out: Path, *flags: str) -> None:
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # as a farm task with 1 CPU
    try:
        assert main(["render", str(shot), "--out", str(out), *flags]) == 0
    finally:
        torch.set_num_threads(threads)


@pytest.fixture(scope="module")
def long_shot(tmp_path_factory):
    """A 40-frame shot (5 chunks of 8) and its single-process tier-1 renders, EXR and MP4."""
    root = tmp_path_factory.mktemp("long")
    shot = make_shot(root / "shots" / "long", 40, 7)
    _one_thread_render(shot, root / "ref", *AUTO)
    _one_thread_render(shot, root / "ref.mp4", *AUTO)
    return root


@pytest.mark.timeout(600)
def test_tier1_shot_split_into_chunks_equals_a_single_process_render(cluster, long_shot, tmp_path):
    settings = RenderSettings(quality="auto", seed=5)
    lines: list[str] = []
    out = tmp_path / "out"
    result = run_farm(find_jobs([long_shot / "shots"]), out, settings, ModelOptions(), chunk_frames=8, write=lines.append, poll_seconds=0.05)
    assert result.ok and sorted(result.done) == ["long"], (result.failed, lines)
    assert_same_frames(long_shot / "ref", out / "long")
    status = state.read_status(out, "long")
    assert status["tier"] == "residual" and status["parts_kind"] == "chunks" and status["parts_total"] == 5 and status["state"] == "done"
    assert sorted(status["task_starts"]) == ["000000-000008", "000008-000016", "000016-000024", "000024-000032", "000032-000040"]
    assert all(len(s) == 1 for s in status["task_starts"].values())
    assert any("chunks" in line and "running" in line for line in lines), lines  # progress: frames and chunks
    assert "done: 40 frames" in lines[-1] and "5 chunks" in lines[-1]
    assert not (out / ".farm" / "long.frames").exists() and not (out / ".farm" / "long.chunks").exists()

    # MP4: the chunks' frames staged, then one encode: the same file as the single-process render's
    mp4 = run_farm(find_jobs([long_shot / "shots"]), tmp_path / "mp4", settings, ModelOptions(), fmt="mp4", chunk_frames=16, write=lambda s: None)
    assert mp4.ok and (tmp_path / "mp4" / "long.mp4").read_bytes() == (long_shot / "ref.mp4").read_bytes()


@pytest.mark.timeout(600)
def test_chunks_finished_by_an_earlier_run_are_not_rendered_again(cluster, long_shot, tmp_path):
    """A farm stopped after some chunks: the next run renders only the others, and the frames are the same."""
    import torch

    from x2video.farm import chunks, task

    settings = RenderSettings(quality="auto", seed=5)
    job = find_jobs([long_shot / "shots"])[0]
    out = tmp_path / "out"
    key = state.job_key(job, settings, ModelOptions(), "exr", None)
    chunks.begin(out, job.name, chunks.digest(key))
    threads = torch.get_num_threads()
    try:
        task.render_chunk(job, out, settings, ModelOptions(), "exr", (8, 16), chunks.digest(key), run="earlier", threads=1)
    finally:
        torch.set_num_threads(threads)
    before = (out / ".farm" / "long.frames" / "000008.exr").stat().st_mtime_ns
    result = run_farm([job], out, settings, ModelOptions(), chunk_frames=8, write=lambda s: None)
    assert result.ok
    starts = state.read_status(out, "long")["task_starts"]
    assert [s["run"] for s in starts["000008-000016"]] == ["earlier"]
    assert all(len(v) == 1 and v[0]["run"] != "earlier" for k, v in starts.items() if k != "000008-000016")
    assert (out / "long" / "000008.exr").stat().st_mtime_ns == before
    assert_same_frames(long_shot / "ref", out / "long")
    # staged frames made with other settings are dropped, not mixed in
    chunks.begin(out, job.name, chunks.digest(key))
    task.render_chunk(job, out, settings, ModelOptions(), "exr", (0, 8), chunks.digest(key), run="old")
    other = RenderSettings(quality="formula", seed=5)
    chunks.begin(out, job.name, chunks.digest(state.job_key(job, other, ModelOptions(), "exr", None)))
    assert not list((out / ".farm" / "long.frames").iterdir())


@pytest.mark.timeout(600)
def test_killed_chunk_worker_is_retried_and_finished_chunks_are_not_redone(cluster, tmp_path):
    from x2video.farm import chunks

    shot = make_shot(tmp_path / "shots" / "big", 48, 11, (112, 160))  # tier 1 at 160x112: a chunk of 12 frames takes about a second
    _one_thread_render(shot, tmp_path / "ref", *AUTO)
    out = tmp_path / "out"
    done_at_kill: dict[str, int] = {}

    def victim() -> dict | None:  # the worker of a chunk that has written frames but is not done
        for p in sorted(chunks.tasks_dir(out, "big").glob("0*.json")):
            rec = chunks.read_task(out, "big", p.stem)
            if not rec.get("done") and (rec.get("frames_done") or 0) > 0:
                for f in (out / ".farm" / "big.frames").glob("*.exr"):
                    done_at_kill[f.name] = f.stat().st_mtime_ns
                done_tasks = [q.stem for q in chunks.tasks_dir(out, "big").glob("0*.json") if chunks.read_task(out, "big", q.stem).get("done")]
                return {**rec, "task": p.stem, "done_tasks": done_tasks}
        return None

    with kill_when(victim, 0.01) as killed:
        result = run_farm(find_jobs([tmp_path / "shots"]), out, RenderSettings(quality="auto", seed=5), ModelOptions(), chunk_frames=12,
                          retries=2, write=lambda s: None, poll_seconds=0.05)
    assert killed, "the killer never saw a chunk running with frames"
    assert result.ok and sorted(result.done) == ["big"], result.failed
    starts = state.read_status(out, "big")["task_starts"]
    assert [s["attempt"] for s in starts[killed["task"]]] == [1, 2] and starts[killed["task"]][0]["pid"] == killed["pid"]
    assert all(len(v) == 1 for k, v in starts.items() if k != killed["task"]), starts  # no other chunk ran twice
    for t in killed["done_tasks"]:  # frames of chunks finished before the kill were not written again
        c, d = (int(x) for x in t.split("-"))
        for f in range(c, d):
            assert (out / "big" / f"{f:06d}.exr").stat().st_mtime_ns == done_at_kill[f"{f:06d}.exr"]
    assert_same_frames(tmp_path / "ref", out / "big")
    assert json.loads((out / "big.done.json").read_text())["attempt"] == 2


# --- one diffusion shot split into its windows ----------------------------------------------------------------

TINY = ["--preset", "fast", "--quality", "diffusion", "--seed", "5", "--untrained"]


def _tiny() -> tuple[RenderSettings, ModelOptions]:
    return RenderSettings(preset="fast", quality="diffusion", seed=5), ModelOptions(untrained=True)


@pytest.fixture(scope="module")
def recursive_shot(tmp_path_factory):
    """33 frames: 3 recursive levels and the seam pass (14 windows of 5 frames), and its single-process render."""
    root = tmp_path_factory.mktemp("recursive")
    shot = make_shot(root / "shots" / "rec", 33, 9)
    _one_thread_render(shot, root / "ref", *TINY)
    return root


@pytest.mark.timeout(600)
def test_diffusion_windows_as_tasks_equal_a_single_process_render(cluster, recursive_shot, tmp_path):
    """Each window a task on 2 workers (a level's windows in parallel once their references exist): the frames equal the
    single-process render bit for bit; a window finished by an earlier run (frames and latents on disk) is reused."""
    import torch

    from x2video.farm import chunks, task

    settings, options = _tiny()
    job = find_jobs([recursive_shot / "shots"])[0]
    out = tmp_path / "out"
    digest = chunks.digest(state.job_key(job, settings, options, "exr", None))
    plan = task.plan_job(job, settings, options)
    assert len(plan["windows"]) == 14 and {w["level"] for w in plan["windows"]} == {1, 2, 3}
    final = {f: i for i, w in enumerate(plan["windows"]) for f in w["generate"]}
    chunks.begin(out, job.name, digest)
    threads = torch.get_num_threads()
    try:  # the keyframe window, rendered by an earlier (stopped) run
        task.render_window(job, out, settings, options, "exr", 0, [f for f in plan["windows"][0]["generate"] if final[f] == 0], digest,
                           "earlier", 1, {})
    finally:
        torch.set_num_threads(threads)
    lines: list[str] = []
    result = run_farm([job], out, settings, options, write=lines.append, poll_seconds=0.05)
    assert result.ok, (result.failed, lines)
    assert_same_frames(recursive_shot / "ref", out / "rec")
    status = state.read_status(out, "rec")
    assert status["parts_kind"] == "windows" and status["parts_total"] == 14 and status["parts_reused"] == 1
    assert [s["run"] for s in status["task_starts"]["w0000"]] == ["earlier"]
    assert all(len(v) == 1 for v in status["task_starts"].values())
    assert any("windows" in line and "running" in line for line in lines), lines


@pytest.mark.timeout(600)
def test_killed_window_worker_is_retried_and_finished_windows_are_not_redone(cluster, recursive_shot, tmp_path):
    from x2video.farm import chunks

    settings, options = _tiny()
    out = tmp_path / "out"

    def victim() -> dict | None:  # once the keyframe window is done, the worker of the next window that starts
        if chunks.read_task(out, "rec", "w0000").get("done"):
            for p in sorted(chunks.tasks_dir(out, "rec").glob("w*.json")):
                rec = chunks.read_task(out, "rec", p.stem)
                if rec.get("starts") and not rec.get("done"):
                    return {**rec, "task": p.stem}
        return None

    with kill_when(victim, 0.005) as killed:
        result = run_farm(find_jobs([recursive_shot / "shots"]), out, settings, options, retries=2, write=lambda s: None, poll_seconds=0.05)
    assert killed, "the killer never saw a window running"
    assert result.ok, result.failed
    starts = state.read_status(out, "rec")["task_starts"]
    assert [s["attempt"] for s in starts[killed["task"]]] == [1, 2] and starts[killed["task"]][0]["pid"] == killed["pid"]
    assert all(len(v) == 1 for k, v in starts.items() if k != killed["task"]), starts  # no finished window ran again
    assert_same_frames(recursive_shot / "ref", out / "rec")


def test_render_windows_one_by_one_equals_render_and_refuses_missing_references():
    """`Renderer.render_windows`, each window in a fresh Renderer given the latents earlier calls returned, gives
    `render`'s frames (in process, a fake model: 33 frames, 3 levels and the seam pass); misuse is refused."""
    import x2video
    from x2video.render.events import FramesReady

    sys.path.insert(0, str(Path(__file__).parent))
    from sampling_fake import FakeModel
    from sampling_fake import make_shot as fake_shot

    shot, settings = fake_shot(33), RenderSettings(preset="fast", seed=5)
    whole: dict[int, np.ndarray] = {}
    x2video.Renderer(FakeModel(has_lcm=True)).render(shot, None, settings, on_event=lambda e: isinstance(e, FramesReady) and whole.update(e.frames))
    plan = x2video.Renderer(FakeModel(has_lcm=True)).render_plan(shot, None, settings)
    assert len(plan) == 14
    latents: dict = {}
    parts: dict[int, np.ndarray] = {}
    for i, w in enumerate(plan):
        made = x2video.Renderer(FakeModel(has_lcm=True)).render_windows(shot, None, settings, [i], {f: latents[f] for f in w.refs},
                                                                        on_event=lambda e: isinstance(e, FramesReady) and parts.update(e.frames))
        latents.update(made[i])
    assert sorted(parts) == sorted(whole) == list(range(33))
    for f in whole:
        np.testing.assert_array_equal(parts[f], whole[f], err_msg=f"frame {f}")
    renderer = x2video.Renderer(FakeModel(has_lcm=True))
    with pytest.raises(ValueError, match=r"window 1 reads frames \[0, 16\] as references: pass their latents"):
        renderer.render_windows(shot, None, settings, [1], {})
    with pytest.raises(ValueError, match="plan order"):
        renderer.render_windows(shot, None, settings, [1, 0], {})
    with pytest.raises(ValueError, match="tier 'formula'.*no windows"):
        renderer.render_plan(shot, None, RenderSettings(quality="formula"))
