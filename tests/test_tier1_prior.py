"""The diffusion tier sampling its residual over tier 1's frame (`ModelConfig.prior` "tier1"): a zero residual renders
exactly what tier 1 renders, the latent cache holds tier 1's frames, and the video and LCM stages train on it."""
from __future__ import annotations

import numpy as np
import pytest
import torch
from train_fixtures import FakeTextEncoder, tiny_dataset, tiny_room

from x2video.model.pipeline import X2VideoModel
from x2video.model.residual import ResidualConfig, ResidualNet


def _tier1_net(seed: int = 0) -> ResidualNet:
    """A small tier-1 net whose output is NOT zero (its zero-initialised head given random weights), so tier 1's frame
    differs from the formula and from the classical shading."""
    torch.manual_seed(seed)
    net = ResidualNet(ResidualConfig(widths=(8, 16)))
    for p in net.parameters():
        if not p.abs().sum():
            torch.nn.init.normal_(p, std=0.05)
    return net.eval()


def _model(net: ResidualNet) -> X2VideoModel:
    from x2video.train.diffusion_stages import zero_output_layer

    m = X2VideoModel.untrained("tiny", seed=3, residual_prior=True, prediction="sample", prior="tier1")
    zero_output_layer(m.unet)  # the UNet predicts a zero residual
    m.lcm_unet = m.unet
    m.residual_net = net
    return m


def _render(model, shot, quality: str, **kw) -> np.ndarray:
    from x2video.render.events import FramesReady
    from x2video.render.renderer import Renderer
    from x2video.render.settings import RenderSettings

    out: dict[int, np.ndarray] = {}
    Renderer(model).render(shot, None, RenderSettings(quality=quality, window=3, base="off", **kw),
                           on_event=lambda e: out.update(e.frames) if isinstance(e, FramesReady) else None)
    return np.stack([out[t] for t in range(shot.num_frames)])


def test_zero_residual_renders_tier_one():
    """With the tier-1 prior, a sampler that adds nothing gives tier 1's frames (to the half-precision detail),
    where with the classical prior it gives the classical shading: the diffusion tier starts from tier 1."""
    shot = tiny_room(7, frames=3, size=(32, 24))
    model = _model(_tier1_net())
    tier1 = _render(model, shot, "residual")
    from x2video.conditioning.frame import plain_conditioning
    from x2video.formula import formula

    base = np.stack([formula(plain_conditioning(shot, t).channels) for t in range(3)])
    assert np.abs(tier1 - base).mean() > 1e-2, "the test's tier-1 net must differ from the formula"
    for sampler, steps in (("ddim", 4), ("lcm", 2)):
        np.testing.assert_allclose(_render(model, shot, "diffusion", sampler=sampler, steps=steps), tier1, atol=3e-3)


def test_prior_image_is_tier_one_and_needs_it():
    from x2video.conditioning.cache import ConditioningCache
    from x2video.conditioning.frame import FrameConditioning, plain_conditioning
    from x2video.tiers.encoder import Encoder
    from x2video.tiers.residual import residual_frames

    shot = tiny_room(8, frames=2, size=(32, 24))
    net = _tier1_net(1)
    model = _model(net)
    fr = plain_conditioning(shot, 0)
    with pytest.raises(ValueError, match="tier 1's frame"):
        model.encode_frames([fr])  # no prior given: the model says what it lacks
    enc = Encoder(model, ConditioningCache())
    enc.with_priors([fr])
    np.testing.assert_array_equal(fr.prior, residual_frames(net, [plain_conditioning(shot, 0)])[0])
    # inside an A|M|R mask the prior is zero, as the classical shading is
    masked = FrameConditioning(dict(fr.channels), np.zeros((24, 32), np.float32), np.zeros((0, 24, 32), np.float32), prior=fr.prior)
    masked.amr_mask[:12] = 1
    img = model.prior_image(masked)
    assert not img[:12].any() and np.array_equal(img[12:], fr.prior[12:])
    # the content key changes with the tier-1 net's weights (the latents of the prior slot do)
    other = _model(_tier1_net(2))
    assert other.content_key() != model.content_key()


@pytest.fixture(scope="module")
def tier1_runs(tmp_path_factory):
    """A tier-1 prior cache of tiny rooms, then one video step from a classical-prior video model and one LCM step."""
    from x2video.train.cache import build_cache
    from x2video.train.diffusion_stages import VideoStageConfig, run_video_stage
    from x2video.train.lcm_stage import LCMStageConfig, run_lcm_stage
    from x2video.train.loop import LoopConfig

    n = torch.get_num_threads()
    torch.set_num_threads(1)
    root = tmp_path_factory.mktemp("tier1")
    ds = tiny_dataset(train=2, test=1, frames=5, size=(32, 24))
    init = X2VideoModel.untrained("tiny", seed=4, residual_prior=True, prediction="sample")  # the classical prior
    init.config.latent_scales = {k: 0.5 for k in init.config.latent_scales}
    init.save_pretrained(root / "init")
    net = _tier1_net(3)
    info = build_cache(ds, init.vae, init.config, root / "cache", text_encoder=FakeTextEncoder(), prior_net=net)
    loop = LoopConfig(steps=1, ckpt_every=1, warmup=1)
    video = run_video_stage(root / "init", root / "cache", root / "video", VideoStageConfig(batch=1, heldout_batches=1), loop)
    lcm = run_lcm_stage(root / "video", root / "cache", root / "lcm", LCMStageConfig(batch=1), loop)
    torch.set_num_threads(n)
    return {"root": root, "info": info, "net": net, "ds": ds, "video": video, "lcm": lcm, "init": init}


def test_cache_holds_tier_one_frames(tier1_runs):
    from x2video.conditioning.frame import FrameConditioning
    from x2video.model.residual_engine import weights_sha
    from x2video.model.vae import encode_mode, images_to_tensor, to_vae_range
    from x2video.tiers.residual import residual_frames
    from x2video.train.cache import TIER1_KEYS, load_split

    info, net = tier1_runs["info"], tier1_runs["net"]
    assert info.prior == "tier1" and info.prior_net == weights_sha(net)
    tr = load_split(tier1_runs["root"] / "cache", "train")
    assert all(k in tr for k in TIER1_KEYS) and "shading_11" not in tr
    # row 1 of tier1_101 (roughness dropped) is the VAE latent of tier 1's frame of those channels
    shot = tier1_runs["ds"]["train"][0]
    ch = {k: shot.channel(k, 1) for k in ("albedo", "normal", "metallic", "irradiance")}
    ch["roughness"] = None
    img = residual_frames(net, [FrameConditioning(ch, np.zeros((24, 32), np.float32), np.zeros((0, 24, 32), np.float32))])[0]
    vae = tier1_runs["init"].vae
    z = encode_mode(vae, images_to_tensor([to_vae_range("shading", img)], torch.device("cpu"), torch.float32), 1)
    torch.testing.assert_close(tr["tier1_101"][1].float(), z[0].half().float(), atol=2e-3, rtol=0)
    assert not torch.equal(tr["tier1_111"], tr["tier1_101"])


def test_video_and_lcm_stages_train_over_tier_one(tier1_runs):
    import json

    from x2video.model.checkpoint import read_config

    for key in ("video", "lcm"):
        cfg = read_config(tier1_runs[key]["model"])
        assert cfg.prior == "tier1" and cfg.residual_prior  # the cache's prior became the model's
        log = json.loads((tier1_runs["root"] / key / "log.json").read_text())
        assert len(log) == 1 and np.isfinite(log[0]["loss"])
    # a tier-1 prior model folder without its tier-1 net refuses to load, and names what is missing
    with pytest.raises(FileNotFoundError, match="residual.safetensors"):
        X2VideoModel.from_pretrained(tier1_runs["lcm"]["model"], text_encoder=FakeTextEncoder())


def test_a_shipped_folder_warns_when_its_tier_one_net_is_not_the_prior_s(tmp_path, caplog):
    """A tier-1-prior model whose residual.safetensors is not the net its training.json says the prior came from loads,
    but says so: the sampler would start from another net's frames."""
    import json
    import logging

    from x2video.model.residual import load, save
    from x2video.model.residual_engine import weights_sha

    net = _tier1_net(5)
    m = _model(net)
    m.save_pretrained(tmp_path)
    save(net, tmp_path)
    sha = weights_sha(load(tmp_path))  # the net as a folder holds it (fp16)
    (tmp_path / "training.json").write_text(json.dumps({"shipped": {"model": {"prior_net": sha}}}))
    with caplog.at_level(logging.WARNING, logger="x2video.model.pipeline"):
        X2VideoModel.from_pretrained(tmp_path, text_encoder=FakeTextEncoder())
    assert "not the one the diffusion model was trained over" not in caplog.text
    save(_tier1_net(6), tmp_path)  # another net copied in alone
    with caplog.at_level(logging.WARNING, logger="x2video.model.pipeline"):
        X2VideoModel.from_pretrained(tmp_path, text_encoder=FakeTextEncoder())
    assert "not the one the diffusion model was trained over" in caplog.text
