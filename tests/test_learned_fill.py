"""The learned keyframe fill (issue 51, tier 1 of the fill): an untrained network is the classical fill exactly, its
input is exposure-free, a training step on a tiny shot writes weights that load and fill, and the CLI runs it."""
from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from test_base_fill import FOV, H, W, pose, wall_shot
from test_keyframe_shots import write_keyframe_shot

from x2video.base.fill import fill_frame, fill_inputs
from x2video.base.keyframes import only_keyframes
from x2video.base.learned import N_PLANES, PLANES, LearnedFill, features, fill_for_tier, light_level, load_learned_fill
from x2video.model.fill_net import FillNet, FillNetConfig, load, save
from x2video.shot import ArrayShot
from x2video.train import fill_data as D
from x2video.train.fill_stage import FillTrainConfig, train

pytestmark = pytest.mark.usefixtures("torch_one_thread")


def glossy_shot(xs=(0.0, 0.05, 0.1, 0.15, 0.2), gain: float = 1.0, hole_at: int | None = 2) -> ArrayShot:
    """`wall_shot` with what the classical fill cannot carry: a highlight that follows the camera (view-dependent),
    an emitter patch, irradiance, roughness and metallic; every light scaled by `gain`."""
    base = wall_shot(list(xs), hole_at=hole_at)
    n = len(xs)
    arrays = {k: np.stack([base.channel(k, t) for t in range(n)]) for k in ("albedo", "normal", "depth", "rgb")}
    ys, xp = np.mgrid[0:H, 0:W].astype(np.float32)
    rgb, emission, irradiance = [], [], []
    for t in range(n):
        albedo = arrays["albedo"][t]
        shading = arrays["rgb"][t] / albedo
        spot = 0.6 * np.exp(-((xp - W / 2 - 40 * xs[t]) ** 2 + (ys - H / 2) ** 2) / 60)[..., None]  # stays near the middle
        emit = np.zeros((H, W, 3), np.float32)
        emit[2:6, 2:8] = (2.0, 1.5, 1.0)
        rgb.append(gain * (albedo * shading + spot + emit))
        emission.append(gain * emit)
        irradiance.append(gain * shading)
    arrays.update(rgb=np.stack(rgb), emission=np.stack(emission), irradiance=np.stack(irradiance),
                  roughness=np.full((n, H, W, 1), 0.3, np.float32), metallic=np.zeros((n, H, W, 1), np.float32))
    return ArrayShot(arrays, poses=[pose(x) for x in xs])


def untrained() -> LearnedFill:
    torch.manual_seed(0)
    return LearnedFill(FillNet(FillNetConfig(N_PLANES)).eval())


def randomised() -> LearnedFill:
    """A network whose last layer is not zero: it changes the fill."""
    lf = untrained()
    with torch.no_grad():
        lf.net.out.weight.normal_(0, 0.05)
    return lf


def test_untrained_network_is_the_classical_fill_bit_for_bit():
    shot = only_keyframes(glossy_shot(), "0,4")
    lf = untrained()
    for t in (1, 2, 3):
        a, b = fill_frame(shot, t), fill_frame(shot, t, learned=lf)
        assert a.rgb.tobytes() == b.rgb.tobytes() and a.holes == b.holes and a.method == b.method
    # by flow too (no depth, no cameras)
    full = glossy_shot()
    flow = only_keyframes(ArrayShot({k: np.stack([full.channel(k, t) for t in range(5)]) for k in ("albedo", "normal", "rgb")}), "0,4")
    assert fill_frame(flow, 2, learned=lf).rgb.tobytes() == fill_frame(flow, 2).rgb.tobytes()
    assert fill_frame(shot, 4, learned=lf).method == "keyframe"


def test_fill_inputs_as_arrays():
    shot = only_keyframes(glossy_shot(), "0,4")
    inp = fill_inputs(shot, 1)
    assert inp.near == (0, 4) and inp.method == "depth" and inp.time_weight == [0.75, 0.25]
    assert [s.shape for s in inp.warped] == [(H, W, 3)] * 2 and [v.shape for v in inp.valid] == [(H, W)] * 2
    assert inp.shading.shape == (H, W, 3) and inp.holes.shape == (H, W) and not inp.holes.any()
    assert fill_inputs(shot, 2).holes.any()  # the box in front of the wall on frame 2
    with pytest.raises(ValueError, match="frame 4 is a keyframe"):
        fill_inputs(shot, 4)


def test_features_are_exposure_free_and_the_output_follows_the_rgb_units():
    a, b = only_keyframes(glossy_shot(), "0,4"), only_keyframes(glossy_shot(gain=8.0), "0,4")
    xa, la = features(a, 2, fill_inputs(a, 2))
    xb, lb = features(b, 2, fill_inputs(b, 2))
    assert xa.shape == (N_PLANES, H, W) == (38, H, W) and len(PLANES) == 18
    assert lb == pytest.approx(8 * la, rel=1e-5)
    np.testing.assert_allclose(xa, xb, atol=1e-4)
    assert np.isfinite(xa).all()
    lf = randomised()
    ra, rb = fill_frame(a, 2, learned=lf).rgb, fill_frame(b, 2, learned=lf).rgb
    assert ra.shape == (H, W, 3) and (ra >= 0).all() and np.isfinite(ra).all()
    np.testing.assert_allclose(rb, 8 * ra, rtol=1e-3, atol=1e-4)
    assert np.abs(ra - fill_frame(a, 2).rgb).max() > 1e-3  # the correction does something


def test_missing_weights_name_the_file(tmp_path):
    with pytest.raises(FileNotFoundError, match="fill.safetensors is missing"):
        load_learned_fill(tmp_path)
    assert fill_for_tier(0) is None
    with pytest.raises(ValueError, match="fill tier 2"):
        fill_for_tier(2)


def test_weights_round_trip_in_fp16(tmp_path):
    lf = randomised()
    save(lf.net, tmp_path, {"step": 3})
    back = load(tmp_path)
    assert json.loads((tmp_path / "fill.json").read_text())["config"]["in_channels"] == N_PLANES
    x = torch.randn(1, N_PLANES, 24, 40)
    with torch.no_grad():
        np.testing.assert_allclose(back(x).numpy(), lf.net(x).numpy(), atol=2e-3)


def test_a_sample_hides_the_frame_between_and_what_it_is_told_to():
    shots = [glossy_shot()]
    rng = np.random.default_rng(0)
    specs = [D.draw(rng, shots, (2, 4, 8, 16), 0.5, 0.5) for _ in range(40)]
    assert all(s.k0 < s.t < s.k1 <= 4 and s.k1 - s.k0 in (2, 4) for s in specs)
    assert {("irradiance" in s.hidden) for s in specs} == {True, False} and {("depth" in s.hidden) for s in specs} == {True, False}
    seen = D.Seen(shots[0], (0, 4), ("irradiance", "depth"))
    assert not seen.has_rgb(2) and not seen.has("irradiance") and seen.info.poses is None
    smp = D.make_sample(shots, D.Spec(0, 0, 4, 2, ("irradiance",)))
    assert smp.x.shape == (N_PLANES, H, W) and smp.x[27:30].max() == 0  # the irradiance planes, hidden
    np.testing.assert_allclose(smp.target.astype(np.float32), shots[0].channel("rgb", 2).transpose(2, 0, 1), rtol=2e-3)
    b = D.crops([smp], rng, 3, 32)
    assert b["x"].shape == (3, N_PLANES, 32, 32) and b["level"].shape == (3, 1, 1, 1)


def test_training_steps_write_weights_that_load_and_fill(tmp_path):
    cfg = FillTrainConfig(steps=6, batch=2, crop=32, pool=4, refresh=1, val_every=3, val_frames=3, ckpt_every=3, lr=5e-4)
    shots = [glossy_shot(), glossy_shot(xs=(0.1, 0.12, 0.16, 0.2, 0.22, 0.26), hole_at=None)]
    held = [glossy_shot(xs=(0.05, 0.07, 0.09, 0.11, 0.13), hole_at=1)]
    summary = train(shots, held, tmp_path, cfg)
    assert summary["steps"] == 6 and len(summary["history"]) == 2
    v = summary["history"][-1]
    assert np.isfinite(v["loss"]) and v["psnr"] > v["psnr_classical"] - 1.0  # a few steps move it, not wreck it
    lf = load_learned_fill(tmp_path / "best")
    meta = json.loads((tmp_path / "best" / "fill.json").read_text())
    assert meta["training"]["steps"] == 6 and "val" in meta
    res = fill_frame(only_keyframes(held[0], "0,4"), 2, learned=lf)
    assert res.rgb.shape == (H, W, 3) and np.isfinite(res.rgb).all()
    # resumes from its checkpoint
    more = train(shots, held, tmp_path, FillTrainConfig(**{**cfg.__dict__, "steps": 8}))
    assert more["steps"] == 8 and len(more["history"]) == 3


def test_light_level_floor():
    assert light_level(np.zeros((2, 2, 3))) == 1e-6


def test_cli_trains_on_blender_shot_folders(tmp_path, capsys):
    from x2video.cli import main as cli

    data = tmp_path / "data"
    for split, n in (("train", 2), ("val", 1)):
        (data / split).mkdir(parents=True)
        for i in range(n):
            write_keyframe_shot(data / split / f"s{i}", frames=5, keys=tuple(range(5)), shot_json={})
    out = tmp_path / "run"
    rc = cli(["train", "fill", "--data", str(data), "--out", str(out), "--steps", "2", "--batch", "2", "--crop", "8",
              "--pool", "2", "--val-frames", "2", "--val-every", "1", "--threads", "1", "--flow-p", "0"])  # 6 x 8: too small for flow
    assert rc == 0
    text = capsys.readouterr().out
    assert "2 steps" in text and "val PSNR" in text
    assert (out / "best" / "fill.safetensors").is_file() and (out / "checkpoint.pt").is_file()
    assert sorted(p.name for p in (out / "cache").iterdir()) == ["train_s0", "train_s1", "val_s0"]
    cached = D.CachedShot(out / "cache" / "train_s0")
    assert {"depth", "emission", "irradiance", "rgb"} <= set(cached.channels) and cached.info.poses[0].fov_y_deg == FOV
    with pytest.raises(SystemExit):
        cli(["train", "fill", "--out", str(out)])  # --data is required


def test_a_shot_with_keyframes_only_is_refused():
    with pytest.raises(ValueError, match="rgb on every frame"):
        D.check_shot(only_keyframes(glossy_shot(), "0,4"), "shot x")


def test_keyframe_bench_runs_the_learned_fill_or_says_why_not(tmp_path, capsys):
    from bench.keyframes import learned_fill, methods

    assert learned_fill(str(tmp_path)) is None
    assert "learned: skipped" in capsys.readouterr().out and "learned" not in methods()
    save(untrained().net, tmp_path)
    fill = learned_fill(str(tmp_path))
    shot = glossy_shot()
    keys = [0, 4]
    got = methods(fill)["learned"](only_keyframes(shot, "0,4"), keys, 2, {})
    np.testing.assert_array_equal(got, methods()["classical"](only_keyframes(shot, "0,4"), keys, 2, {}))
