"""Two-step smoke tests of every training stage (vae -> cache -> image -> video -> lcm) on tiny configs, with resume."""
from __future__ import annotations

import json
from pathlib import Path

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
    ds = tiny_dataset(train=2, test=1, val=1, frames=9, size=(32, 24))
    loop = LoopConfig(steps=2, ckpt_every=1, warmup=1)
    vstage = VAEStageConfig(vae_channels=(16, 32), crop=16, batch=4, pool_frames_per_room=4, eval_frames_per_room=1)
    out = {"root": root, "ds": ds}
    out["vae"] = run_vae_stage(ds["train"], ds["test"], root / "vae", vstage, loop)
    out["vae_log2"] = json.loads((root / "vae" / "log.json").read_text())
    out["vae_resumed"] = run_vae_stage(ds["train"], ds["test"], root / "vae", vstage, LoopConfig(steps=3, ckpt_every=1, warmup=1))
    cfg, vae = load_vae(root / "vae")
    out["cache_info"] = build_cache(ds, vae, cfg, root / "cache", text_encoder=FakeTextEncoder(), scale_frames=4)
    istage = ImageStageConfig(unet_channels=(16, 32), batch=2, heldout_batches=1)
    out["image"] = run_image_stage(root / "cache", root / "image", istage, loop)
    out["video"] = run_video_stage(root / "image", root / "cache", root / "video", VideoStageConfig(batch=1, heldout_batches=1), loop)
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
    assert img.unet.config.in_channels == 27 and vid.unet.config.in_channels == 32  # shading prior from the image stage on
    assert img.residual_prior and vid.residual_prior and lcm.residual_prior  # the residual target is carried forward
    img_w = img.unet.conv_in.weight[:, :23]
    vid_w = vid.unet.conv_in.weight[:, :23]
    assert 0 < float((img_w - vid_w).abs().max()) < 0.1
    for key in ("image", "video", "lcm"):
        res = json.loads((runs["root"] / key / "results.json").read_text())[key]
        assert res["step"] == 2 and res["speed"]["steps_per_s"] > 0
        log = json.loads((runs["root"] / key / "log.json").read_text())
        assert len(log) == 2 and all(np.isfinite(h["loss"]) for h in log)
        if key != "lcm":
            assert set(res["heldout_v_loss"]) == {"full", "augmented"} and all(0 < v < 10 for v in res["heldout_v_loss"].values())
            assert res["heldout_split"] == "val"  # runs are compared on the validation rooms, never the test rooms (issue 49)
    assert {r["split"] for r in runs["cache_info"].rooms} == {"train", "val", "test"}


def _frame_conditioning(shot, t, keep, amr=None):
    from x2video.conditioning.frame import FrameConditioning

    H, W = shot.size
    ch = {}
    for name in ("albedo", "normal", "roughness", "metallic", "irradiance"):
        x = shot.channel(name, t).copy() if keep[name] else None
        if x is not None and amr is not None and name in ("albedo", "roughness", "metallic"):
            x[amr > 0.5] = 0  # what a "Mask A|M|R" edit gives
        ch[name] = x
    mask = np.zeros((H, W), np.float32) if amr is None else amr.astype(np.float32)
    return FrameConditioning(channels=ch, amr_mask=mask, local_masks=np.zeros((0, H, W), np.float32), frame_index=t)


@pytest.mark.parametrize("dropped", [(), ("normal",), ("metallic",), ("albedo", "roughness"), ("irradiance",)])
def test_training_conditioning_equals_inference_encode_frames(runs, dropped):
    """Dropout on cached latents gives what X2VideoModel.encode_frames gives for the same dropped channels."""
    from x2video.model.pipeline import X2VideoModel
    from x2video.train.batches import CHANNELS, LatentData

    model = X2VideoModel.from_pretrained(runs["video"]["model"], text_encoder=FakeTextEncoder())
    data = LatentData(runs["root"] / "cache", "train", model.config.latent_scales, shading_prior=True)
    shot, t = runs["ds"]["train"][1], 3
    keep = {c: c not in dropped for c in CHANNELS}
    train_cond = data.conditioning(torch.tensor([9 + t]), keep, None)[0]
    infer_cond = model.encode_frames([_frame_conditioning(shot, t, keep)])[0]
    assert train_cond.shape == infer_cond.shape == (24, 12, 16)
    torch.testing.assert_close(train_cond, infer_cond, rtol=2e-3, atol=2e-3)  # cache stores float16


def test_amr_mask_zeroes_latents_like_inference(runs):
    from x2video.model.pipeline import X2VideoModel
    from x2video.model.vae import area_downsample
    from x2video.train.batches import CHANNELS, LatentData

    model = X2VideoModel.from_pretrained(runs["video"]["model"], text_encoder=FakeTextEncoder())
    data = LatentData(runs["root"] / "cache", "train", model.config.latent_scales, shading_prior=True)
    shot, t = runs["ds"]["train"][0], 2
    amr = (shot.channel("ids", t)[..., 0] == 1).astype(np.float32)
    assert 0 < amr.mean() < 0.5
    keep = {c: True for c in CHANNELS}
    tr = data.conditioning(torch.tensor([t]), keep, torch.from_numpy(amr)[None, None])[0]
    inf = model.encode_frames([_frame_conditioning(shot, t, keep, amr)])[0]
    m = area_downsample(torch.from_numpy(amr)[None, None], (12, 16))[0, 0]
    torch.testing.assert_close(tr[19], m)
    torch.testing.assert_close(inf[19], m)
    inside = m > 0.999
    assert inside.any()
    for sl in (slice(0, 4), slice(8, 12), slice(12, 16), slice(20, 24)):  # albedo, roughness, metallic, shading
        assert tr[sl][:, inside].abs().max() == 0 and inf[sl][:, inside].abs().max() == 0
    torch.testing.assert_close(tr[4:8], inf[4:8], rtol=2e-3, atol=2e-3)  # normal untouched by the mask


def test_batches_windows_masks_and_prompts(runs):
    from x2video.model.checkpoint import read_config
    from x2video.train.batches import AugmentConfig, LatentData, WindowConfig

    cfg = read_config(runs["root"] / "cache" / "model")
    data = LatentData(runs["root"] / "cache", "train", cfg.latent_scales, shading_prior=True)
    rng = np.random.default_rng(0)
    wc = WindowConfig(frames=3, levels=3, short_p=0.0)
    seen_levels = set()
    for _ in range(30):
        windows, mode, level, refs = data.random_windows(rng, 2, wc)
        k = level if mode == "interp" else None
        for rows in windows:
            assert len(rows) == 3 and len({int(data.row_room[r]) for r in rows}) == 1
            steps = {abs(b - a) for a, b in zip(rows, rows[1:])}
            assert len(steps) == 1
            if k is not None:
                assert steps == {2 ** (k - 1)}
                seen_levels.add(k)
        assert refs in (((), (0, 2)) if mode == "interp" else ((), (0,)))
    assert seen_levels == {1, 2, 3}

    aug = AugmentConfig(channel_drop_p=0.0, prompt_drop_p=0.0, mask_p=1.0, max_masks=2, local_prompt_p=1.0)
    windows, mode, level, refs = data.random_windows(rng, 2, wc)
    b = data.sample(rng, windows, aug, mode="key", level=3, ref_positions=(0,))
    assert b.cond.shape == (6, 24, 12, 16) and b.x0.shape == (6, 4, 12, 16)
    assert b.text_local is not None and b.local_masks.shape[:2] == (6, b.text_local.shape[1])
    torch.testing.assert_close(b.ref[0], b.x0[0]) and torch.testing.assert_close(b.ref[3], b.x0[3])
    assert b.ref[1].abs().max() == 0 and b.ref[5].abs().max() == 0
    for w, rows in enumerate(windows):
        room = data.room_by_index[int(data.row_room[rows[0]])]
        torch.testing.assert_close(b.text_global[w], data.text[data.prompt_index[room["caption"]]])
        for p in range(b.text_local.shape[1]):
            m = b.local_masks[w * 3, p]
            if m.sum() == 0:
                assert b.text_local[w, p].abs().max() == 0  # padding
                continue
            obj = int(data.ids[rows[0]][m > 0][0])
            torch.testing.assert_close(m, (data.ids[rows[0]] == obj).float())
            torch.testing.assert_close(b.text_local[w, p], data.text[data.prompt_index[room["objects"][str(obj)]]])
            assert float(b.cond[w * 3, 19][m[::2, ::2] > 0].min()) > 0  # the object is inside the A|M|R union mask


def test_cli_image_stage_runs_and_resumes(runs, tmp_path, capsys):
    from x2video.cli import main

    args = ["train", "image", "--cache", str(runs["root"] / "cache"), "--out", str(tmp_path / "img"), "--unet-channels", "16,32",
            "--batch", "2", "--warmup", "1", "--threads", "1", "--no-shading-prior", "--heldout-batches", "1"]
    assert main(args + ["--steps", "1"]) == 0
    assert main(args + ["--steps", "2"]) == 0
    res = json.loads((tmp_path / "img" / "results.json").read_text())["image"]
    assert res["step"] == 2 and res["shading_prior"] is False and res["speed"]["first_step"] == 1
    assert main(["train", "image", "--cache", str(tmp_path / "nope"), "--out", str(tmp_path / "x")]) == 2
    assert "nope" in capsys.readouterr().err
    for flag in ("--channel-drop", "--mask-p", "--ref-shift-p"):  # every augmentation probability is checked, by name
        assert main(args + ["--steps", "3", flag, "1.5"]) == 2
        assert f"{flag} must be a probability in [0, 1], got 1.5" in capsys.readouterr().err
    assert json.loads((tmp_path / "img" / "results.json").read_text())["image"]["step"] == 2  # and nothing trained


def test_ship_writes_fp16_model_with_training_size(runs):
    from safetensors.torch import load_file

    from x2video.eval.data import training_size
    from x2video.model.pipeline import X2VideoModel
    from x2video.train.ship import ship

    out = runs["root"] / "resources" / "x2video-tiny"
    info = ship(runs["root"] / "lcm", out, image=runs["root"] / "image", runs=[runs["root"] / "video"])
    assert training_size(out) == tuple(info["size"]) == (32, 24)
    for part in ("unet", "vae", "lcm_unet"):
        sd = load_file(str(out / f"{part}.safetensors"))
        assert all(v.dtype == torch.float16 for v in sd.values() if v.is_floating_point())
    doc = json.loads((out / "training.json").read_text())
    assert doc["runs"]["video"]["results"]["video"]["step"] == 2
    model = X2VideoModel.from_pretrained(out, text_encoder=FakeTextEncoder())
    ref = X2VideoModel.from_pretrained(runs["lcm"]["model"], text_encoder=FakeTextEncoder())
    assert model.has_lcm and (out / "image" / "unet.safetensors").is_file()
    w, w_ref = model.unet.conv_in.weight, ref.unet.conv_in.weight
    assert float((w - w_ref).abs().max()) < 1e-3 * float(w_ref.abs().max()) + 1e-4  # fp16 rounding only
    with pytest.raises(FileExistsError, match="--overwrite"):
        ship(runs["root"] / "lcm", out)
    ship(runs["root"] / "video", out, overwrite=True)  # replaced in place, no lcm any more
    assert not (out / "lcm_unet.safetensors").exists() and not list(out.parent.glob(".x2video-tiny*"))


def test_residual_target_is_rgb_minus_prior_latent(runs):
    """The residual model's diffusion target: RGB latent minus the shading latent; where the prior is
    absent (irradiance dropped) that latent is zero and the target is the RGB latent itself."""
    from x2video.model.checkpoint import read_config
    from x2video.train.batches import AugmentConfig, LatentData
    from x2video.train.diffusion import diffusion_batch

    cfg = read_config(runs["root"] / "cache" / "model")
    data = LatentData(runs["root"] / "cache", "train", cfg.latent_scales, shading_prior=True)
    rng = np.random.default_rng(0)
    b = data.sample(rng, data.random_frames(rng, 6), AugmentConfig(channel_drop_p=0.0, prompt_drop_p=0.0, mask_p=0.0))
    r = diffusion_batch(b, residual=True)
    torch.testing.assert_close(r.x0, b.x0 - b.cond[:, -4:])
    assert float(b.cond[:, -4:].abs().mean()) > 0.1  # a real prior was subtracted
    assert diffusion_batch(b, residual=False) is b
    assert r.ref is b.ref  # references stay RGB latents
    b.cond[:, -4:] = 0  # what dropping irradiance gives
    torch.testing.assert_close(diffusion_batch(b, residual=True).x0, b.x0)


def test_image_stage_init_starts_from_the_given_weights(runs, tmp_path):
    """--init loads the image model; with lr 0 the saved (EMA) weights are exactly the init's.
    An init of another architecture fails naming it."""
    from x2video.model.pipeline import X2VideoModel
    from x2video.train.diffusion_stages import ImageStageConfig, run_image_stage

    stage = ImageStageConfig(unet_channels=(16, 32), batch=2, heldout_batches=0, init=str(runs["root"] / "image"))
    res = run_image_stage(runs["root"] / "cache", tmp_path / "img", stage, LoopConfig(steps=1, lr=0.0, warmup=0))
    got = X2VideoModel.from_pretrained(res["model"], text_encoder=FakeTextEncoder()).unet.state_dict()
    want = X2VideoModel.from_pretrained(runs["image"]["model"], text_encoder=FakeTextEncoder()).unet.state_dict()
    assert got.keys() == want.keys() and all(torch.equal(got[k], want[k]) for k in want)
    bad = ImageStageConfig(unet_channels=(16, 32), batch=2, heldout_batches=0, shading_prior=False, init=str(runs["root"] / "image"))
    with pytest.raises(ValueError, match="not an image model of this stage's architecture"):
        run_image_stage(runs["root"] / "cache", tmp_path / "bad", bad, LoopConfig(steps=1))


def test_video_stage_continues_a_video_model(runs, tmp_path):
    """--init with a video model continues it without conversion (lr 0: same weights) and may switch
    the diffusion target; it cannot change the shading-prior layout."""
    from x2video.model.pipeline import X2VideoModel
    from x2video.train.diffusion_stages import VideoStageConfig, run_video_stage

    res = run_video_stage(runs["root"] / "video", runs["root"] / "cache", tmp_path / "v",
                          VideoStageConfig(batch=1, heldout_batches=0, residual_prior=False), LoopConfig(steps=1, lr=0.0, warmup=0))
    got = X2VideoModel.from_pretrained(res["model"], text_encoder=FakeTextEncoder())
    want = X2VideoModel.from_pretrained(runs["video"]["model"], text_encoder=FakeTextEncoder())
    assert got.config.video and not got.residual_prior and want.residual_prior
    sd, ref = got.unet.state_dict(), want.unet.state_dict()
    assert sd.keys() == ref.keys() and all(torch.equal(sd[k], ref[k]) for k in ref)
    with pytest.raises(ValueError, match="cannot change"):
        run_video_stage(runs["root"] / "video", runs["root"] / "cache", tmp_path / "w",
                        VideoStageConfig(batch=1, heldout_batches=0, shading_prior=False), LoopConfig(steps=1))


def test_video_stage_moves_the_zero_initialised_alphas_at_their_own_rate(runs, tmp_path):
    """The Hybrid Self-Attention alphas get `alpha_lr_mult` times the UNet's learning rate (Adam's
    first step moves a parameter by at most its rate); every other weight moves at the base rate."""
    from x2video.model.pipeline import X2VideoModel
    from x2video.train.diffusion_stages import VideoStageConfig, run_video_stage

    lr = 1e-5
    res = run_video_stage(runs["root"] / "video", runs["root"] / "cache", tmp_path / "v",
                          VideoStageConfig(batch=1, heldout_batches=0, alpha_lr_mult=1000.0),
                          LoopConfig(steps=1, lr=lr, warmup=0, ema_decay=0.0))
    got = X2VideoModel.from_pretrained(res["model"], text_encoder=FakeTextEncoder()).unet.state_dict()
    want = X2VideoModel.from_pretrained(runs["video"]["model"], text_encoder=FakeTextEncoder()).unet.state_dict()
    moved = {k: float((got[k].float() - want[k].float()).abs().max()) for k in want}
    alphas = [k for k in moved if k.endswith(("alpha_r", "alpha_t"))]
    assert len(alphas) >= 2
    assert max(moved[k] for k in alphas) > 100 * lr
    assert max(v for k, v in moved.items() if k not in alphas) <= 1.01 * lr


def test_ref_shift_moves_target_and_references_alike_per_object(runs):
    """--ref-shift-p: a window with references gets one offset per object (constant over the object's
    pixels, following it from frame to frame) plus one for the window, added to its target and its
    references alike; windows without references, and p = 0, stay the ground truth."""
    from x2video.model.checkpoint import read_config
    from x2video.model.vae import area_downsample
    from x2video.train.batches import AugmentConfig, LatentData, object_shift

    cfg = read_config(runs["root"] / "cache" / "model")
    data = LatentData(runs["root"] / "cache", "train", cfg.latent_scales, shading_prior=True)
    room = data.rooms[0]
    windows = [[room["start"] + i for i in (0, 2, 4)], [room["start"] + i for i in (4, 6, 8)]]
    rows = torch.as_tensor([r for w in windows for r in w])
    gt = data.lat["rgb"][rows].float()  # (6, 4, h, w)
    plain = AugmentConfig(channel_drop_p=0.0, prompt_drop_p=0.0, mask_p=0.0)
    shifted = AugmentConfig(channel_drop_p=0.0, prompt_drop_p=0.0, mask_p=0.0, ref_shift_p=1.0, ref_shift_std=0.5)
    for aug, refs in ((plain, (0, 2)), (shifted, ())):
        b = data.sample(np.random.default_rng(3), windows, aug, mode="interp", level=2, ref_positions=refs)
        torch.testing.assert_close(b.x0, gt)
    b = data.sample(np.random.default_rng(3), windows, shifted, mode="interp", level=2, ref_positions=(0, 2))
    d = b.x0 - gt  # (6, 4, h, w)
    assert float(d.abs().mean()) > 0.01  # moved...
    for p in (0, 2, 3, 5):  # ...and the references carry the same shift as the target
        torch.testing.assert_close(b.ref[p], b.x0[p])
    assert not torch.equal(d[:3], d[3:])  # each window draws its own offsets
    # the shift is exactly a per-object offset spread by the objects' area-downsampled coverage
    ids = data.ids[rows[:3]].long()  # (3, H, W)
    uniq = torch.unique(ids)
    cover = area_downsample((ids[:, None] == uniq[None, :, None, None]).float(), data.latent_size)  # (3, K, h, w)
    design = torch.cat([cover, torch.ones_like(cover[:, :1])], dim=1).permute(0, 2, 3, 1).reshape(-1, uniq.numel() + 1)
    target = d[:3].permute(0, 2, 3, 1).reshape(-1, 4)
    coef = torch.linalg.lstsq(design, target).solution
    torch.testing.assert_close(design @ coef, target, atol=1e-4, rtol=0)
    # a pure latent pixel of one object moves by that object's offset (+ the window's) in every frame
    full = cover.amax(dim=1) > 0.999  # (3, h, w) latent pixels covered by one object
    k = cover.argmax(dim=1)  # (3, h, w)
    for obj in range(uniq.numel()):
        sel = full & (k == obj)
        if int(sel.sum()) >= 2:
            vals = d[:3].permute(0, 2, 3, 1)[sel]  # (S, 4)
            torch.testing.assert_close(vals, vals[:1].expand_as(vals), atol=1e-5, rtol=0)
    z = object_shift(ids, data.latent_size, torch.zeros(gt.shape[1]), np.random.default_rng(0))
    assert z.shape == (3, 4, *data.latent_size) and z.abs().max() == 0  # std 0: no shift


def test_video_stage_train_only_interp_leaves_the_keyframe_path_bit_identical(runs, tmp_path):
    """--train-only interp: only the temporal interp<k> and reference r1 LoRA branches move, so
    keyframe-mode and sequential windows render exactly as before; it refuses keyframe batches and
    image models, whose training could not reach those branches."""
    from x2video.model.pipeline import X2VideoModel
    from x2video.train.batches import WindowConfig
    from x2video.train.diffusion_stages import VideoStageConfig, interp_branch_parameters, run_video_stage

    stage = VideoStageConfig(batch=1, heldout_batches=0, train_only="interp", window=WindowConfig(interp_p=1.0, ref_p_interp=1.0))
    res = run_video_stage(runs["root"] / "video", runs["root"] / "cache", tmp_path / "v", stage,
                          LoopConfig(steps=2, lr=1e-3, warmup=0, ema_decay=0.0))
    got = X2VideoModel.from_pretrained(res["model"], text_encoder=FakeTextEncoder()).unet.state_dict()
    want = X2VideoModel.from_pretrained(runs["video"]["model"], text_encoder=FakeTextEncoder()).unet.state_dict()
    assert got.keys() == want.keys()
    video = X2VideoModel.from_pretrained(runs["video"]["model"], text_encoder=FakeTextEncoder()).unet
    ids = {id(p) for p in interp_branch_parameters(video)}
    trained = {k for k, p in video.named_parameters() if id(p) in ids}
    assert trained and all(".lora.interp" in k or ".ref.lora.r1." in k for k in trained)
    assert not any(".lora.key." in k or ".lora.r0." in k or k.endswith(("alpha_r", "alpha_t")) for k in trained)
    assert all(torch.equal(got[k], want[k]) for k in want if k not in trained)
    assert any(not torch.equal(got[k], want[k]) for k in trained)
    with pytest.raises(ValueError, match="--interp-p 1"):
        run_video_stage(runs["root"] / "video", runs["root"] / "cache", tmp_path / "w",
                        VideoStageConfig(batch=1, heldout_batches=0, train_only="interp"), LoopConfig(steps=1))
    with pytest.raises(ValueError, match="holds an image model"):
        run_video_stage(runs["root"] / "image", runs["root"] / "cache", tmp_path / "x", stage, LoopConfig(steps=1))


def test_cache_from_a_model_folder_keeps_its_latent_scales(runs, tmp_path):
    """A new cache encoded with a trained model's VAE keeps that model's latent scales (instead of
    measuring its own), so the model can be trained further on it; a VAE run has none and measures."""
    from x2video.model.checkpoint import read_config
    from x2video.train.cache import build_cache
    from x2video.train.diffusion_stages import VideoStageConfig, run_video_stage
    from x2video.train.runs import load_vae

    cfg, vae = load_vae(runs["video"]["model"])
    other = {"train": runs["ds"]["train"][1:], "test": runs["ds"]["test"]}  # other frames: measuring would give other scales
    build_cache(other, vae, cfg, tmp_path / "cache", text_encoder=FakeTextEncoder(), scale_frames=4)
    assert read_config(tmp_path / "cache" / "model").latent_scales == cfg.latent_scales
    assert cfg.latent_scales == read_config(runs["root"] / "cache" / "model").latent_scales
    res = run_video_stage(runs["video"]["model"], tmp_path / "cache", tmp_path / "v", VideoStageConfig(batch=1, heldout_batches=0),
                          LoopConfig(steps=1, lr=0.0, warmup=0))
    assert res["step"] == 1
    vcfg, _ = load_vae(runs["root"] / "vae")
    assert all(v == 1.0 for v in vcfg.latent_scales.values())  # the VAE run's: measured by the first cache


def check_batch_workers(root: str) -> None:
    """The body of `test_batch_workers_draw_valid_distinct_batches`, run in a fresh interpreter."""
    from x2video.model.checkpoint import read_config
    from x2video.train.batches import AugmentConfig, LatentData, WindowConfig, video_batches

    cfg = read_config(Path(root) / "cache" / "model")
    data = LatentData(Path(root) / "cache", "train", cfg.latent_scales, shading_prior=True)
    wc, aug = WindowConfig(frames=3, levels=2), AugmentConfig()
    inproc = video_batches(data, 2, aug, wc, seed=3, workers=0)
    a, b = next(inproc(0)), next(inproc(0))
    torch.testing.assert_close(a.x0, b.x0)  # same seed and start step: same first batch
    c = next(inproc(5))
    assert c.x0.shape != a.x0.shape or not torch.equal(c.x0, a.x0)  # a resumed run draws afresh

    it = video_batches(data, 2, aug, wc, seed=3, workers=2)(0)
    got = [next(it) for _ in range(6)]
    for g in got:
        assert g.x0.dim() == 4 and g.x0.shape[1:] == (4, 12, 16) and g.cond.shape[0] == g.x0.shape[0]
        assert g.x0.shape[0] == 2 * g.num_frames and g.text_global.shape[0] == 2
        assert torch.isfinite(g.cond).all()
        if g.ref is not None:
            assert g.ref.shape == g.x0.shape
    # the two workers alternate; their seeds differ, so their first batches differ
    assert not (got[0].x0.shape == got[1].x0.shape and torch.equal(got[0].x0, got[1].x0))


def test_batch_workers_draw_valid_distinct_batches(runs):
    """--workers: batches drawn in forked DataLoader workers are the same kind of batch as in-process
    ones, workers draw different samples, and workers=0 keeps the in-process sequence reproducible.

    Run in a fresh interpreter, as `x2video train` runs: in this test process, after the OpenVINO engine
    tests (test_engine.py), forking the workers crashed the whole process (SIGSEGV) under pytest's output
    capture; a script that renders with OpenVINO and then forks DataLoader workers runs fine, so the crash
    is the test process's state, not the trainer's."""
    import subprocess
    import sys

    here = str(Path(__file__).resolve().parent)
    code = f"import sys; sys.path.insert(0, {here!r}); import test_train_stages as t; t.check_batch_workers({str(runs['root'])!r})"
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]


def test_window_noise_shares_the_fraction_within_windows_only():
    from x2video.train.diffusion import window_noise

    x0 = torch.zeros(3 * 4, 4, 32, 32)  # 3 windows of 4 frames
    g = torch.Generator().manual_seed(0)
    flat = window_noise(x0, 4, 0.95, g).reshape(12, -1).double()
    assert torch.allclose(flat.std(1), torch.ones(12, dtype=torch.float64), atol=0.04)
    corr = torch.corrcoef(flat)
    same = torch.block_diag(*[torch.ones(4, 4, dtype=torch.bool)] * 3) & ~torch.eye(12, dtype=torch.bool)
    other = ~torch.block_diag(*[torch.ones(4, 4, dtype=torch.bool)] * 3)
    assert torch.allclose(corr[same], torch.full_like(corr[same], 0.95), atol=0.02)
    assert corr[other].abs().max() < 0.06
    indep = torch.corrcoef(window_noise(x0, 4, 0.0, g).reshape(12, -1))
    assert indep[~torch.eye(12, dtype=torch.bool)].abs().max() < 0.06
    with pytest.raises(ValueError, match="whole windows"):
        window_noise(torch.zeros(10, 4, 2, 2), 4, 0.5)


def test_video_stage_trains_and_scores_with_the_shared_noise(runs, tmp_path):
    """--noise-shared: the windows' noise (training and held-out) is the renderer's mixed prior; with
    the weights held (lr 0) the held-out v-loss is then measured on other noise than without it."""
    from x2video.train.diffusion_stages import VideoStageConfig, run_video_stage

    loop = LoopConfig(steps=1, lr=0.0, warmup=0)
    plain = run_video_stage(runs["root"] / "video", runs["root"] / "cache", tmp_path / "a", VideoStageConfig(batch=1, heldout_batches=1), loop)
    shared = run_video_stage(runs["root"] / "video", runs["root"] / "cache", tmp_path / "b",
                             VideoStageConfig(batch=1, heldout_batches=1, noise_shared=0.95), loop)
    assert plain["heldout_v_loss"] and shared["heldout_v_loss"] and plain["heldout_v_loss"] != shared["heldout_v_loss"]
    with pytest.raises(ValueError, match="noise-shared must lie in"):
        run_video_stage(runs["root"] / "video", runs["root"] / "cache", tmp_path / "c",
                        VideoStageConfig(batch=1, heldout_batches=0, noise_shared=1.5), loop)


def test_ship_keep_runs_carries_the_replaced_lineage(runs, tmp_path):
    """A model continued from the shipped one keeps the shipped folder's run records and sources;
    without a training.json to keep, --keep-runs fails naming the file."""
    from x2video.train.ship import ship

    out = tmp_path / "resources" / "x2video-tiny"
    first = ship(runs["root"] / "video", out, runs=[runs["root"] / "video"])
    ship(runs["root"] / "lcm", out, runs=[runs["root"] / "lcm"], overwrite=True, keep_runs=True)
    doc = json.loads((out / "training.json").read_text())
    assert set(doc["runs"]) == {"video", "lcm"}
    assert doc["runs"]["video"]["results"]["video"]["step"] == 2
    assert doc["previous"] == [first["parts"]]
    assert doc["shipped"]["model"]["source"] != first["parts"]["model"]["source"]
    ship(runs["root"] / "lcm", out, overwrite=True, keep_runs=True)  # a second replacement stacks up
    doc2 = json.loads((out / "training.json").read_text())
    assert len(doc2["previous"]) == 2 and doc2["previous"][1] == first["parts"] and set(doc2["runs"]) == {"video", "lcm"}
    (out / "training.json").unlink()
    with pytest.raises(FileNotFoundError, match="training.json"):
        ship(runs["root"] / "lcm", out, overwrite=True, keep_runs=True)


def test_lcm_student_init_starts_from_the_given_student(runs, tmp_path):
    """--student-init: with lr 0 the saved student is exactly the init's lcm_unet (not the teacher's
    UNet), the teacher stays the given video model, and a folder without an LCM UNet fails naming it."""
    from safetensors.torch import load_file

    from x2video.train.lcm_stage import LCMStageConfig, run_lcm_stage
    from x2video.train.loop import LoopConfig

    init = Path(runs["lcm"]["model"])
    teacher = runs["root"] / "video"
    res = run_lcm_stage(teacher, runs["root"] / "cache", tmp_path / "lcm2", LCMStageConfig(batch=1),
                        LoopConfig(steps=1, lr=0.0, warmup=0, ckpt_every=1), student_init=init)
    got = load_file(str(Path(res["model"]) / "lcm_unet.safetensors"))
    want = load_file(str(init / "lcm_unet.safetensors"))
    teacher_sd = load_file(str(Path(res["model"]) / "unet.safetensors"))
    assert got.keys() == want.keys()
    assert all(torch.equal(got[k], want[k]) for k in got)
    assert any(not torch.equal(got[k], teacher_sd[k]) for k in got)  # the init's student moved away from its teacher
    state = json.loads((Path(res["checkpoint"]) / "state.json").read_text())
    assert state["stage_config"]["student_init"] == str(init.resolve())
    with pytest.raises(FileNotFoundError, match="lcm_unet"):
        run_lcm_stage(teacher, runs["root"] / "cache", tmp_path / "lcm3", LCMStageConfig(batch=1), LoopConfig(steps=1),
                      student_init=teacher)


def test_encoder_stage_distils_the_channel_encoder_and_ships_with_the_teacher(runs, tmp_path):
    """`x2video train encoder`: the run's model is the teacher's parts bit for bit plus channel_encoder; training
    brings the attention-free encoder closer to the full one on held-out rooms; it resumes; "distilled" then
    encodes the channels with it (slot = student latent x scale), "vae" ignores it, and it ships in fp16."""
    from safetensors.torch import load_file

    from x2video.eval.data import training_size
    from x2video.model.channel_encoder import ChannelEncoder
    from x2video.model.checkpoint import load_into
    from x2video.model.pipeline import X2VideoModel
    from x2video.model.vae import to_vae_range
    from x2video.train.encoder_stage import EncoderStageConfig, run_encoder_stage
    from x2video.train.ship import ship

    teacher = Path(runs["lcm"]["model"])
    ds = runs["ds"]
    stage = EncoderStageConfig(batch=8, pool_frames_per_room=4, eval_frames_per_room=2)
    res = run_encoder_stage(teacher, ds["train"], ds["test"], tmp_path / "enc", stage,
                            LoopConfig(steps=30, lr=2e-4, warmup=2, ckpt_every=30, ema_decay=0))
    held, start = res["heldout"], res["heldout_untrained"]
    assert set(held) == {"albedo", "normal", "roughness", "metallic", "shading", "all"}
    assert held["shading"]["images"] == 2 * held["albedo"]["images"]  # full prior + one dropped-channel variant
    assert start["all"]["relative_mse"] > 0  # dropping the attention changes the latents ...
    assert held["all"]["relative_mse"] < 0.7 * start["all"]["relative_mse"], (start, held)  # ... and training closes the gap
    model = Path(res["model"])
    for part in ("unet", "vae", "lcm_unet"):
        a, b = load_file(str(model / f"{part}.safetensors")), load_file(str(teacher / f"{part}.safetensors"))
        assert a.keys() == b.keys() and all(torch.equal(a[k], b[k].to(a[k].dtype)) for k in a)
    resumed = run_encoder_stage(teacher, ds["train"], ds["test"], tmp_path / "enc", stage,
                                LoopConfig(steps=31, lr=2e-4, warmup=2, ckpt_every=30, ema_decay=0))
    assert resumed["step"] == 31 and len(json.loads((tmp_path / "enc" / "log.json").read_text())) == 31

    fast = X2VideoModel.from_pretrained(model, text_encoder=FakeTextEncoder(), channel_encoder="distilled")
    vae = X2VideoModel.from_pretrained(model, text_encoder=FakeTextEncoder(), channel_encoder="vae")
    auto = X2VideoModel.from_pretrained(model, text_encoder=FakeTextEncoder(), channel_encoder="auto")
    assert fast.channel_encoder is not None and auto.channel_encoder is not None and vae.channel_encoder is None
    assert fast.content_key() != vae.content_key() and fast.content_key() == auto.content_key()
    shot = ds["test"][0]
    frames = [_frame_conditioning(shot, t, {c: True for c in ("albedo", "normal", "roughness", "metallic", "irradiance")}) for t in (0, 1)]
    got, ref = fast.encode_frames(frames), vae.encode_frames(frames)
    student = ChannelEncoder(fast.config.vae)
    load_into(student, model / "channel_encoder.safetensors", "channel_encoder")
    x = torch.from_numpy(np.stack([to_vae_range("albedo", f.channels["albedo"]) for f in frames])).permute(0, 3, 1, 2)
    with torch.no_grad():
        want = student(x) * fast.config.latent_scales["albedo"]
    torch.testing.assert_close(got[:, 0:4], want, rtol=1e-4, atol=1e-5)
    assert not torch.allclose(got[:, 0:4], ref[:, 0:4])  # the VAE's latents are what "vae" gives
    torch.testing.assert_close(got[:, 16:19], ref[:, 16:19])  # irradiance is not VAE-encoded either way
    with pytest.raises(FileNotFoundError, match="channel_encoder.safetensors"):
        X2VideoModel.from_pretrained(teacher, text_encoder=FakeTextEncoder(), channel_encoder="distilled")

    out = tmp_path / "resources" / "x2video-tiny"
    ship(tmp_path / "enc", out)
    assert training_size(out) == (32, 24)  # followed from the encoder run to its teacher's cache
    sd = load_file(str(out / "channel_encoder.safetensors"))
    assert sd and all(v.dtype == torch.float16 for v in sd.values()) and not any("attention" in k for k in sd)
    assert X2VideoModel.from_pretrained(out, text_encoder=FakeTextEncoder(), channel_encoder="auto").channel_encoder is not None


def test_channel_encoder_is_the_vae_encoder_without_its_attention(runs):
    """Started from a VAE, the student shares every encoder tensor but the mid-block attention's, and gives
    the VAE's latents exactly once that attention is switched off in the VAE itself."""
    from x2video.model.channel_encoder import ChannelEncoder
    from x2video.model.vae import encode_mode
    from x2video.train.runs import load_vae

    cfg, vae = load_vae(runs["root"] / "vae")
    enc = ChannelEncoder.from_vae(vae, cfg.vae)
    sd, full = enc.state_dict(), vae.state_dict()
    assert all(torch.equal(v, full[k]) for k, v in sd.items())
    assert {k for k in full if k.startswith(("encoder.", "quant_conv.")) and k not in sd} == \
        {k for k in full if k.startswith("encoder.mid_block.attentions.")}
    x = torch.rand(2, 3, 24, 32) * 2 - 1
    with torch.no_grad():
        got = enc(x)
        assert got.shape == (2, 4, 12, 16) and not torch.allclose(got, encode_mode(vae, x))
        vae.encoder.mid_block.attentions[0].forward = lambda h, temb=None: h  # the attention as identity
        torch.testing.assert_close(got, encode_mode(vae, x))
    with pytest.raises(ValueError, match="not a multiple of 2"):
        enc(torch.randn(1, 3, 9, 12))


def test_cli_encoder_stage_and_eval_refuses_mixed_channel_encoders(runs, tmp_path, capsys):
    """`x2video train encoder` from the command line (size from the teacher's run), and `x2video eval` refusing a
    video and an LCM model that would encode the channels differently (table d compares samplers, not encoders)."""
    from x2video.cli import build_parser, main
    from x2video.cli.eval import load_models
    from x2video.procedural.shotgen import write_procedural_shot

    data = tmp_path / "data"
    write_procedural_shot(data / "train" / "room_00000", 0, 3, 32, 24, overwrite=True)
    write_procedural_shot(data / "test" / "room_00001", 1, 3, 32, 24, overwrite=True)
    teacher = runs["root"] / "lcm"
    args = ["train", "encoder", "--teacher", str(teacher), "--data", str(data), "--out", str(tmp_path / "enc"), "--steps", "2",
            "--pool-frames", "2", "--eval-frames", "1", "--batch", "4", "--warmup", "1", "--threads", "1"]
    assert main(args) == 0
    res = json.loads((tmp_path / "enc" / "results.json").read_text())["encoder"]
    assert res["step"] == 2 and res["heldout"]["all"]["images"] == 6
    base = ["eval", "--data", str(data), "--out", str(tmp_path / "ev")]
    a = build_parser().parse_args(base + ["--weights", str(tmp_path / "enc"), "--lcm-weights", str(teacher), "--channel-encoder", "auto"])
    with pytest.raises(ValueError, match="pick vae or distilled"):
        load_models(a, with_image=False)
    a = build_parser().parse_args(base + ["--weights", str(tmp_path / "enc"), "--channel-encoder", "distilled"])
    models, _ = load_models(a, with_image=False)
    assert models.info["video"]["channel_encoder"] == "distilled" and models.video.channel_encoder is not None
    assert main(["train", "encoder", "--teacher", str(tmp_path / "nope"), "--data", str(data), "--out", str(tmp_path / "x")]) == 2
    assert "nope" in capsys.readouterr().err


def test_as_8bit_quantises_like_a_png_export():
    """Tier-1 format augmentation: the channels as an 8-bit PNG export holds them, the log formula following."""
    from x2video.channels import linear_to_srgb
    from x2video.model import residual as R
    from x2video.train.residual_stage import as_8bit

    rng = np.random.default_rng(0)
    n = rng.normal(size=(6, 5, 3))
    ch = {"albedo": rng.uniform(0, 1, (6, 5, 3)), "normal": n / np.linalg.norm(n, axis=-1, keepdims=True),
          "roughness": rng.uniform(0, 1, (6, 5)), "metallic": rng.uniform(0, 1, (6, 5)), "irradiance": rng.uniform(0, 3, (6, 5, 3))}
    x, _ = R.features(ch)
    q = x.copy()
    as_8bit(q, irradiance=True)
    codes = linear_to_srgb(q[0:3]) * 255
    assert np.allclose(codes, np.round(codes), atol=1e-3), "albedo lies on sRGB code values"
    assert np.allclose(q[6:8] * 255, np.round(q[6:8] * 255), atol=1e-4)
    assert np.allclose(np.linalg.norm(q[3:6], axis=0), 1, atol=1e-5) and np.abs(q[3:6] - x[3:6]).max() < 0.02
    ir = np.expm1(q[8:11])
    assert np.allclose(q[11:14], np.log1p(q[0:3] * ir), atol=1e-5), "the log formula follows the quantised channels"
    assert ir.max() <= np.percentile(np.expm1(x[8:11]), 99) * 1.0001, "8-bit irradiance clips above its white point"
    assert np.abs(q - x).max() > 0, "something was quantised"
