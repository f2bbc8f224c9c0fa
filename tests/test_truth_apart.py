"""A truth apart from the passes (`SHOT/truth/`, `x2video dataset truth`): the readers prefer it and say so, fall back to
the shot's rgb without it, refuse an unfinished one; the command parses and refuses what it cannot rebuild; and, where
bpy is installed, a tiny real Cycles room gets a truth in the Combined's units that is not the Combined."""
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from x2video.channels import tonemap
from x2video.io import load_shot
from x2video.io.image import write_exr
from x2video.io.shotdir import write_shot_folder
from x2video.io.truth import FORMAT, OWN, ground_truth, summary, truth_frame_path
from x2video.shot import ArrayShot

bpy_missing = subprocess.run([sys.executable, "-c", "import importlib.util,sys; sys.exit(importlib.util.find_spec('bpy') is None)"],
                             check=False).returncode


def _shot(folder: Path, frames: int = 3, size: tuple[int, int] = (12, 16)) -> Path:
    rng = np.random.default_rng(0)
    t, (h, w) = frames, size
    normal = np.zeros((t, h, w, 3), np.float32)
    normal[..., 2] = 1
    arrays = {"albedo": rng.uniform(0.1, 0.9, (t, h, w, 3)), "normal": normal, "roughness": np.full((t, h, w, 1), 0.5),
              "metallic": np.zeros((t, h, w, 1)), "irradiance": rng.uniform(0.2, 1.0, (t, h, w, 3)), "rgb": rng.uniform(0.1, 0.8, (t, h, w, 3))}
    return write_shot_folder(ArrayShot(arrays, fps=10.0), folder)


def _truth(shot_dir: Path, frames: int, factor: float = 1.5, complete: bool = True, skip: tuple[int, ...] = ()) -> list[np.ndarray]:
    """truth/ = the shot's rgb x `factor` (a picture the readers can tell from the rgb), record beside it."""
    shot = load_shot(shot_dir)
    out = []
    for t in range(frames):
        a = shot.channel("rgb", t) * factor
        out.append(a)
        if t not in skip:
            write_exr(truth_frame_path(shot_dir, t), {c: a[..., i] for i, c in enumerate("RGB")}, "float")
    (shot_dir / "truth" / "truth.json").write_text(json.dumps({"format": FORMAT, "samples": 64, "seed": 1, "frames": frames, "complete": complete,
                                                               "seconds": {}, "cpu_seconds": {}}))
    return out


def test_readers_prefer_the_truth_apart_and_fall_back_to_rgb(tmp_path):
    from bench.ptscore import truth, truth_label

    d = _shot(tmp_path / "data" / "test" / "room_a")
    shot = load_shot(d)
    own = ground_truth(shot)
    assert own.label == OWN and not own.apart
    assert np.array_equal(own.frame(1), shot.channel("rgb", 1))
    assert truth_label([shot]) == OWN
    assert np.array_equal(truth(shot)[1], tonemap(shot.channel("rgb", 1)))

    want = _truth(d, 3)
    shot = load_shot(d)  # the loader is not confused by the folder beside the frames
    assert shot.num_frames == 3 and "rgb" in shot.channels
    gt = ground_truth(shot)
    assert gt.apart and gt.label == "apart, 64 spp seed 1"
    assert np.allclose(gt.frame(2), want[2], rtol=1e-6) and not np.allclose(gt.frame(2), shot.channel("rgb", 2))
    assert np.allclose(truth(shot, 2)[1], tonemap(want[1]), atol=1e-6) and len(truth(shot, 2)) == 2
    assert truth_label([shot]) == "apart, 64 spp seed 1"
    assert np.array_equal(shot.channel("rgb", 0), load_shot(d).channel("rgb", 0)), "the shot's own rgb (an input) is untouched"

    # x2video eval: the truth apart, resized as the channels are, and the label on the shot
    from x2video.eval.data import load_eval_shots

    ev = load_eval_shots(tmp_path / "data", "test", frames=2, size=(8, 6))[0]
    assert ev.truth == "apart, 64 spp seed 1" and ev.gt[0].shape == (6, 8, 3)
    assert ev.gt[0].mean() == pytest.approx(float(want[0].mean()), rel=1e-3)


def test_an_unfinished_truth_is_an_error_naming_the_missing_frame(tmp_path):
    d = _shot(tmp_path / "room_b")
    _truth(d, 3, complete=False, skip=(2,))
    with pytest.raises(ValueError, match=r"unfinished \(frame 2 missing"):
        ground_truth(load_shot(d))
    _truth(d, 2)  # a truth of fewer frames than the shot
    with pytest.raises(ValueError, match="a truth of 2 frames, the shot has 3"):
        ground_truth(load_shot(d))


def test_summary_and_stability_case_truth(tmp_path):
    assert summary([OWN, OWN]) == OWN
    assert summary(["apart, 64 spp seed 1", OWN, OWN]) == "mixed: apart, 64 spp seed 1 (1 shot); the passes' own Combined (2 shots)"
    from bench.stability_cells import Context, case_truth
    from bench.stability_shots import ViewShot

    d = _shot(tmp_path / "room_c")
    want = _truth(d, 3, factor=2.0)
    src = load_shot(d)
    ctx = Context([src], truths=[ground_truth(src)])
    view = ViewShot(src, 5, (6, 8))  # ping-pong: frame 4 is source frame 0, at half size
    fn = case_truth({"family": "length", "params": {"frames": 5, "size": [8, 6]}}, ctx, view)
    assert fn is not None and fn(4).shape == (6, 8, 3) and fn(4).mean() == pytest.approx(float(want[0].mean()), rel=1e-3)
    assert case_truth({"family": "length", "params": {}}, Context([src]), view) is None  # no truths: the case shot's rgb


def test_truth_command_parses_and_refuses_what_it_cannot_rebuild(tmp_path, capsys):
    from x2video.cli import build_parser
    from x2video.cycles.truth import make_truth

    args = build_parser().parse_args(["dataset", "truth", "--data", str(tmp_path)])
    assert (args.split, args.samples, args.seed, args.threads) == ("test", 0, 1, 0) and args.func.__name__ == "_truth"
    args = build_parser().parse_args(["dataset", "truth", "--data", str(tmp_path), "--split", "val,test", "--samples", "64", "--seed", "2"])
    assert (args.split, args.samples, args.seed) == ("val,test", 64, 2)
    _shot(tmp_path / "test" / "room_d")  # a shot of our own format: no Cycles scene behind it
    with pytest.raises(SystemExit, match="no extra.light_gain"):
        make_truth(args)
    with pytest.raises(ValueError, match="the passes' own noise seed"):
        make_truth(build_parser().parse_args(["dataset", "truth", "--data", str(tmp_path), "--seed", "0"]))


@pytest.mark.slow
@pytest.mark.skipif(bool(bpy_missing), reason="bpy is not installed: `pip install -e '.[cycles]'` (scripts/setup.sh does)")
def test_truth_of_a_tiny_cycles_room_is_in_the_combineds_units_and_not_the_combined(tmp_path, capsys):
    from bench.ptscore import truth_label

    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    nice = {"preexec_fn": lambda: os.nice(10)} if hasattr(os, "nice") else {}
    x2v = [sys.executable, "-m", "x2video", "dataset"]
    out = tmp_path / "set"
    make = subprocess.run(x2v + ["make", "--renderer", "cycles", "--rooms", "1", "--frames", "2", "--size", "32x24", "--samples", "4",
                                 "--test-every", "1", "--seed", "3", "--out", str(out)], capture_output=True, text=True, timeout=300, env=env, **nice)
    assert make.returncode == 0, make.stderr[-3000:]
    cmd = x2v + ["truth", "--data", str(out), "--split", "test", "--threads", "1"]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=300, env=env, **nice)
    assert proc.returncode == 0, proc.stderr[-3000:]
    room = out / "test" / "room_00000"
    rec = json.loads((room / "truth" / "truth.json").read_text())
    assert rec["complete"] and (rec["samples"], rec["seed"]) == (32, 1) and rec["passes"] == {"samples": 4, "seed": 0, "denoise": True}
    assert rec["scene"] == {"kind": "room", "seed": 3 * 1000003, "version": 3} and rec["renderer"].startswith("Cycles")
    assert set(rec["seconds"]) == set(rec["cpu_seconds"]) == {"0", "1"} and min(rec["cpu_seconds"].values()) > 0
    shot = load_shot(room)
    gt = ground_truth(shot)
    assert gt.label == "apart, 32 spp seed 1" == truth_label([shot])
    for t in range(2):
        a, combined = gt.frame(t), shot.channel("rgb", t)
        assert np.isfinite(a).all() and a.shape == combined.shape
        assert float(a.mean()) == pytest.approx(float(combined.mean()), rel=0.10), "the same scene, camera and exposure"
        assert a.tobytes() != combined.tobytes() and np.abs(a - combined).mean() > 1e-4, "another render, not a copy"
    from x2video.cli import build_parser
    from x2video.cycles.truth import make_truth

    assert make_truth(build_parser().parse_args(cmd[3:])) == 0  # resumable: nothing left, no Blender started
    assert "1 had their truth apart, 0 rendered now" in capsys.readouterr().out
