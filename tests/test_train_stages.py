"""Two-step smoke tests of every training stage (vae -> cache -> image -> video -> lcm) on tiny configs, with resume."""
from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from train_fixtures import FakeTextEncoder, tiny_dataset
from x2video.train.loop import LoopConfig, list_checkpoints


@pytest.fixture(scope="module")
def one_thread():
    n = torch.get_num_threads()
    torch.set_num_threads(1)  # 2 shared cores: one thread is several times faster than two fighting
    yield
    torch.set_num_threads(n)


@pytest.fixture(scope="module")
def runs(tmp_path_factory, one_thread):
    """vae (2 steps, then resumed to 3) -> cache -> image (2) -> video (2) -> lcm (2), in one temp folder."""
    from x2video.train.cache import build_cache
    from x2video.train.diffusion_stages import ImageStageConfig, VideoStageConfig, run_image_stage, run_video_stage
    from x2video.train.lcm_stage import LCMStageConfig, run_lcm_stage
    from x2video.train.runs import load_vae
    from x2video.train.vae_stage import VAEStageConfig, run_vae_stage

    root = tmp_path_factory.mktemp("train")
    ds = tiny_dataset(train=2, test=1, frames=9, size=(32, 24))
    loop = LoopConfig(steps=2, ckpt_every=1, warmup=1)
    vstage = VAEStageConfig(vae_channels=(16, 32), crop=16, batch=4, pool_frames_per_room=4, eval_frames_per_room=1)
    out = {"root": root, "ds": ds}
    out["vae"] = run_vae_stage(ds["train"], ds["test"], root / "vae", vstage, loop)
    out["vae_log2"] = json.loads((root / "vae" / "log.json").read_text())
    out["vae_resumed"] = run_vae_stage(ds["train"], ds["test"], root / "vae", vstage, LoopConfig(steps=3, ckpt_every=1, warmup=1))
    cfg, vae = load_vae(root / "vae")
    out["cache_info"] = build_cache(ds, vae, cfg, root / "cache", text_encoder=FakeTextEncoder(), scale_frames=4)
    istage = ImageStageConfig(unet_channels=(16, 32), batch=2)
    out["image"] = run_image_stage(root / "cache", root / "image", istage, loop)
    out["video"] = run_video_stage(root / "image", root / "cache", root / "video", VideoStageConfig(batch=1), loop)
    out["lcm"] = run_lcm_stage(root / "video", root / "cache", root / "lcm", LCMStageConfig(batch=1), loop)
    return out


def test_vae_stage_reports_heldout_psnr_and_resumes(runs):
    r = runs["vae"]
    assert r["step"] == 2 and r["latent_factor"] == 2
    assert set(r["heldout_psnr_db"]) == {"rgb", "albedo", "normal", "roughness", "metallic", "mean"}
    assert all(np.isfinite(v) and v > 0 for v in r["heldout_psnr_db"].values())
    res = json.loads((runs["root"] / "vae" / "results.json").read_text())
    assert res["vae"]["step"] == 3  # the resumed run overwrote the result
    log = json.loads((runs["root"] / "vae" / "log.json").read_text())
    assert [h["step"] for h in log] == [1, 2, 3]  # continued from 2, no step repeated
    assert log[:2] == runs["vae_log2"]
    assert [c.name for c in list_checkpoints(runs["root"] / "vae")] == ["step-000000002", "step-000000003"]
    state = json.loads((runs["root"] / "vae" / "step-000000003" / "state.json").read_text())
    assert state["step"] == 3 and state["stage_config"]["stage"] == "vae"
    summary = json.loads((runs["root"] / "vae" / "summary.json").read_text())
    assert summary["first_step"] == 2 and summary["steps_run"] == 1 and summary["steps_per_s"] > 0


def test_cache_holds_every_frame_and_scales(runs):
    from x2video.model.checkpoint import read_config
    from x2video.train.cache import SHADING_KEYS, load_split, load_text

    info = runs["cache_info"]
    root = runs["root"] / "cache"
    assert info.size == (32, 24) and info.latent_size == (12, 16)
    tr = load_split(root, "train")
    assert tr["rgb"].shape == (18, 4, 12, 16) and tr["irradiance"].shape == (18, 3, 12, 16) and tr["ids"].shape == (18, 24, 32)
    assert all(tr[k].shape == (18, 4, 12, 16) for k in SHADING_KEYS)
    assert load_split(root, "test")["rgb"].shape[0] == 9
    # the irradiance is in [-1, 1] and the ids match the shots' ids
    assert float(tr["irradiance"].float().abs().max()) <= 1.0
    shot = runs["ds"]["train"][1]
    np.testing.assert_array_equal(tr["ids"][9 + 4].numpy(), shot.channel("ids", 4)[..., 0])
    scales = read_config(root / "model").latent_scales
    assert all(v > 0 and v != 1.0 for v in scales.values())
    assert load_text(root).shape == (len(info.prompts), 8, 384) and "" in info.prompts
    # metallic-free / specular-free shading variants differ from the full one where the shot has metal
    assert not torch.equal(tr["shading_11"], tr["shading_00"])


def test_image_video_lcm_stages_load_as_models(runs):
    from x2video.model.pipeline import X2VideoModel

    img = X2VideoModel.from_pretrained(runs["image"]["model"], text_encoder=FakeTextEncoder())
    assert not img.config.video and img.config.shading_prior
    vid = X2VideoModel.from_pretrained(runs["video"]["model"], text_encoder=FakeTextEncoder())
    assert vid.config.video and not vid.has_lcm
    lcm = X2VideoModel.from_pretrained(runs["lcm"]["model"], text_encoder=FakeTextEncoder())
    assert lcm.has_lcm
    # the video stage started from the image weights (conv_in's old channels) and then moved
    img_w = img.unet.conv_in.weight
    vid_w = vid.unet.conv_in.weight[:, : img_w.shape[1]]
    assert 0 < float((img_w - vid_w).abs().max()) < 0.1
    for key in ("image", "video", "lcm"):
        res = json.loads((runs["root"] / key / "results.json").read_text())[key]
        assert res["step"] == 2 and res["speed"]["steps_per_s"] > 0
        log = json.loads((runs["root"] / key / "log.json").read_text())
        assert len(log) == 2 and all(np.isfinite(h["loss"]) for h in log)
