"""The Cycles back end for real: a two-frame procedural room path-traced at a tiny size, read back through the Blender loader."""
import json
import os
import subprocess
import sys

import numpy as np
import pytest

from x2video.channels import INTRINSIC

bpy_missing = subprocess.run([sys.executable, "-c", "import importlib.util,sys; sys.exit(importlib.util.find_spec('bpy') is None)"]).returncode


@pytest.mark.slow
@pytest.mark.skipif(bool(bpy_missing), reason="bpy is not installed: `pip install -e '.[cycles]'` (scripts/setup.sh does)")
def test_cycles_room_renders_and_loads(tmp_path, monkeypatch):
    from x2video.io import load_shot
    from x2video.io.image import read_image

    out = tmp_path / "pt"
    cmd = [sys.executable, "-m", "x2video", "dataset", "make", "--renderer", "cycles", "--rooms", "1", "--frames", "2", "--clips", "2",
           "--size", "48x32", "--samples", "4", "--workers", "1", "--test-every", "0", "--seed", "3", "--out", str(out)]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=600, env={**os.environ, "PYTHONUNBUFFERED": "1"})
    assert proc.returncode == 0, proc.stderr[-3000:]
    meta = json.loads((out / "dataset.json").read_text())
    # one room built once, rendered as two clips of two frames along their own camera paths
    assert meta["complete"] and meta["renderer"] == "cycles" and meta["splits"]["train"] == ["train/room_00000", "train/room_00000_c1"]
    assert meta["frames"] == 2 and meta["split_frames"]["train"] == 4 and meta["builds"][-1]["frames"] == 4 and meta["builds"][-1]["frames_per_hour"] > 0
    assert meta["variety"]["rooms"] == 1 and set(meta["variety"]["light"]) <= {"day", "night", "mixed", "lamp-only"}
    # the same command again resumes (nothing left to render) and keeps the settings, the totals and the build record
    again = subprocess.run(cmd, capture_output=True, text=True, timeout=600, env={**os.environ, "PYTHONUNBUFFERED": "1"})
    assert again.returncode == 0, again.stderr[-3000:]
    assert "1 done, 0 to path-trace" in again.stdout, again.stdout[-2000:]
    meta2 = json.loads((out / "dataset.json").read_text())
    assert meta2["frames"] == 2 and meta2["split_frames"] == meta["split_frames"] and len(meta2["builds"]) == 2
    c0 = json.loads((out / "train" / "room_00000" / "cameras.json").read_text())
    c1 = json.loads((out / "train" / "room_00000_c1" / "cameras.json").read_text())
    assert c0 != c1, "each clip follows its own camera path"
    room = out / "train" / "room_00000"
    shot = load_shot(room)
    assert shot.num_frames == 2 and shot.size == (32, 48)
    # the five channels, the ground truth and ids come through the user's Blender loader, poses from cameras.json
    for ch in (*INTRINSIC, "rgb", "ids"):
        assert ch in shot.info.channels, ch
    assert shot.info.poses is not None and len(shot.info.poses) == 2
    assert shot.info.extra["passes"]["irradiance"].endswith("DiffDir + .DiffInd")
    fr = shot.frame(1)
    lit = np.linalg.norm(fr["normal"], axis=-1) > 0.5
    assert lit.mean() > 0.5, "most of a room view is geometry"
    assert np.allclose(np.linalg.norm(fr["normal"][lit], axis=-1), 1, atol=1e-2)
    assert fr["irradiance"][lit].mean() > 0 and fr["rgb"].max() > 0
    # Cycles' exact split: Combined = DiffCol (DiffDir + DiffInd) + GlossCol (GlossDir + GlossInd) + Trans + Emit + Env
    img = read_image(sorted(room.glob("frame_*.exr"))[1])
    g = lambda p: img.stack([f"{p}.{c}" for c in "RGB"])  # noqa: E731
    split = (g("DiffCol") * (g("NoisyDiffDir") + g("NoisyDiffInd")) + g("GlossCol") * (g("GlossDir") + g("GlossInd"))
             + g("TransCol") * (g("TransDir") + g("TransInd")) + g("Emit") + g("Env"))
    noisy_combined_mean, split_mean = float(g("Combined").mean()), float(split.mean())
    assert split_mean == pytest.approx(noisy_combined_mean, rel=0.25)
    info = json.loads((room / "shot.json").read_text())
    assert info["extra"]["renderer"].startswith("Cycles") and info["extra"]["samples"] == 4
    # bench.light_budget on this set: adding Cycles' own passes to the formula brings it to the truth
    from bench.light_budget import main as light_budget

    monkeypatch.setattr("bench.light_budget.results_path", lambda bench, name: tmp_path / "lb" / f"{name}.json")
    assert light_budget(["--data", str(out), "--split", "train", "--step", "1", "--name", "t"]) == 0
    lb = json.loads((tmp_path / "lb" / "t.json").read_text())["summary"]
    assert lb["+ every pass"] > lb["formula"] + 3 and lb["+ every pass"] > 24  # 4 spp, denoised passes vs denoised Combined
    # ... and it scores against a truth apart when the room has one (here the Combined at a quarter of its light: the
    # passes no longer add up to it), and says so
    from x2video.io.image import write_exr
    from x2video.io.truth import FORMAT, RECORD, TRUTH_DIR, truth_frame_path

    for clip in (room, room.with_name("room_00000_c1")):
        clip_shot = load_shot(clip)
        for t in range(2):
            truth_frame_path(clip, t).parent.mkdir(exist_ok=True)
            rgb = 0.25 * clip_shot.channel("rgb", t)
            write_exr(truth_frame_path(clip, t), {c: rgb[..., i] for i, c in enumerate("RGB")}, "float")
        (clip / TRUTH_DIR / RECORD).write_text(json.dumps({"format": FORMAT, "samples": 8, "seed": 7, "frames": 2, "complete": True}))
    assert light_budget(["--data", str(out), "--split", "train", "--step", "1", "--name", "t2"]) == 0
    lb2 = json.loads((tmp_path / "lb" / "t2.json").read_text())
    assert lb2["truth"] == "apart, 8 spp seed 7" and lb2["summary"]["+ every pass"] < lb["+ every pass"] - 6
    # the room writes its material classes (every object id in the ids pass that is not background is classed)
    from x2video.cycles.classes import CLASSES, material_classes

    classes = material_classes(info)
    assert classes and set(classes.values()) <= set(CLASSES)
    ids = {int(i) for i in np.unique(fr["ids"]) if int(i) != 0}
    assert ids <= set(classes), sorted(ids - set(classes))


@pytest.mark.slow
@pytest.mark.skipif(bool(bpy_missing), reason="bpy is not installed: `pip install -e '.[cycles]'` (scripts/setup.sh does)")
def test_cycles_clip_trains_tier1_one_step(tmp_path, monkeypatch):
    """A two-frame Cycles clip of a v3 room (textures, decor), read back and used for one tier-1 training step
    with every augmentation on (noisy passes, exposure, 8-bit formats); then a latent cache of tier 1's frames made
    with that net, and one step of the video and the LCM stage over it from the shipped diffusion weights."""
    from x2video.train.residual_stage import ResidualTrainConfig, train

    out = tmp_path / "pt"
    cmd = [sys.executable, "-m", "x2video", "dataset", "make", "--renderer", "cycles", "--rooms", "3", "--frames", "2",
           "--size", "32x24", "--samples", "2", "--workers", "1", "--test-every", "3", "--seed", "5", "--out", str(out)]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    info = json.loads((out / "train" / "room_00000" / "shot.json").read_text())
    assert info["extra"]["generator"] == "x2video.cycles v3" and info["extra"]["path_traced"]["variety"] is not None
    cfg = ResidualTrainConfig(steps=1, batch=2, crop=16, val_every=1, ckpt_every=1, noisy_p=1.0, format_aug=1.0, widths=(8, 16))
    summary = train(out, tmp_path / "run", cfg, threads=1)
    assert summary["steps"] == 1 and summary["train_frames"] == 2 and summary["val_split"] == "val"
    assert np.isfinite(summary["best_val_psnr"])
    assert (tmp_path / "run" / "best" / "residual.safetensors").is_file()
    # bench.pathtraced scores tier 1 on this set beside the formula, also with 3 objects' A|M|R masked out (PSNR inside them)
    from bench.pathtraced import main as pathtraced

    monkeypatch.setattr("bench.pathtraced.results_path", lambda bench, name: tmp_path / "ptb" / f"{name}.json")
    assert pathtraced(["--data", str(out), "--split", "test", "--tiers", "formula,residual", "--conditions", "all,mask_amr",
                       "--threads", "1", "--name", "t"]) == 0
    res = json.loads((tmp_path / "ptb" / "t.json").read_text())["summary"]
    assert {"albedo_x_irradiance|all", "formula|all", "residual|all", "residual|mask_amr", "auto|all"} <= set(res)
    assert res["auto|all"]["psnr"] > 5  # what --quality auto renders of the whole shot, scored beside the tiers
    assert "psnr_in_masks" in res["residual|mask_amr"] and "psnr_in_masks" not in res["residual|all"]
    assert np.isfinite(res["residual|mask_amr"]["psnr_in_masks"]) and res["residual|all"]["psnr"] > 5
    assert np.isfinite(res["residual|all"]["psnr_mask_ring"])  # the band around the masks, in every row (auto's seam)
    # the diffusion tier over tier 1 (`ModelConfig.prior` "tier1"): a latent cache of tier 1's frames made with the net just
    # trained, then one video step from the shipped weights and one LCM step from that
    import torch
    from train_fixtures import FakeTextEncoder

    from x2video.model.checkpoint import read_config
    from x2video.model.residual import load as load_residual
    from x2video.model.residual_engine import weights_sha
    from x2video.train.cache import build_cache
    from x2video.train.data import open_dataset
    from x2video.train.diffusion_stages import VideoStageConfig, run_video_stage
    from x2video.train.lcm_stage import LCMStageConfig, run_lcm_stage
    from x2video.train.loop import LoopConfig
    from x2video.train.runs import load_vae
    from x2video.weights import shipped_weights

    shipped = shipped_weights()
    cfg_v, vae = load_vae(shipped)
    net = load_residual(tmp_path / "run" / "best").eval()
    info = build_cache(open_dataset(out, need_test=False), vae, cfg_v, tmp_path / "cache", text_encoder=FakeTextEncoder(), prior_net=net)
    assert info.prior == "tier1" and info.prior_net == weights_sha(net) and info.size == (32, 24)
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        loop = LoopConfig(steps=1, ckpt_every=1, warmup=1)
        video = run_video_stage(shipped, tmp_path / "cache", tmp_path / "video", VideoStageConfig(batch=1, heldout_batches=0), loop)
        lcm = run_lcm_stage(tmp_path / "video", tmp_path / "cache", tmp_path / "lcm", LCMStageConfig(batch=1), loop)
    finally:
        torch.set_num_threads(n)
    for run in (video, lcm):
        cfg = read_config(run["model"])
        assert cfg.prior == "tier1" and cfg.residual_prior and cfg.video
    assert np.isfinite(json.loads((tmp_path / "lcm" / "log.json").read_text())[0]["loss"])
