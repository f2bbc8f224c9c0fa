"""X2VideoModel end to end on the tiny preset: conditioning layout, schedule, window batching, checkpoints."""
from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from diffusers import DDIMScheduler

from x2video.conditioning.frame import FrameConditioning
from x2video.model.api import RenderModel, WindowInputs
from x2video.model.config import ModelConfig, preset
from x2video.model.inputs import run_unet
from x2video.model.pipeline import X2VideoModel
from x2video.model.unet import hybrid_processors

H, W = 64, 96  # pixels; latents 8x12 at f=8


@pytest.fixture(scope="module")
def model() -> X2VideoModel:
    return X2VideoModel.untrained("tiny", seed=0)


def _frame(i: int, drop: tuple[str, ...] = (), amr: np.ndarray | None = None) -> FrameConditioning:
    rng = np.random.default_rng(i)
    n = rng.normal(size=(H, W, 3)).astype(np.float32)
    n[..., 2] = np.abs(n[..., 2]) + 0.5
    ch = {
        "albedo": rng.random((H, W, 3), dtype=np.float32),
        "normal": n / np.linalg.norm(n, axis=-1, keepdims=True),
        "roughness": rng.random((H, W, 1), dtype=np.float32),
        "metallic": rng.random((H, W, 1), dtype=np.float32),
        "irradiance": rng.random((H, W, 3), dtype=np.float32) * 3,
    }
    for d in drop:
        ch[d] = None
    mask = np.zeros((H, W), np.float32) if amr is None else amr
    return FrameConditioning(ch, mask, np.zeros((0, H, W), np.float32), frame_index=i)


def _window(model: X2VideoModel, cond: torch.Tensor, text: torch.Tensor) -> WindowInputs:
    n = cond.shape[0]
    return WindowInputs(cond, torch.zeros(n, 4, *cond.shape[-2:]), (0,), "key", 1, text, text[:0], torch.zeros(n, 0, H, W))


def test_untrained_model_satisfies_the_render_contract(model):
    assert isinstance(model, X2VideoModel) and model.is_untrained
    assert model.content_key().startswith("untrained-")
    rm: RenderModel = model  # structural check for type checkers
    assert rm.downsample == 8 and rm.latent_channels == 4 and not rm.has_lcm
    cond = model.encode_frames([_frame(i) for i in range(3)])
    assert cond.shape == (3, 24, H // 8, W // 8)
    text = torch.randn(1, 32, 384)
    v = model.predict_v(torch.randn(3, 4, H // 8, W // 8), torch.tensor(999), _window(model, cond, text))
    assert v.shape == (3, 4, H // 8, W // 8) and torch.isfinite(v).all()
    rgb = model.decode(v)
    assert rgb.shape == (3, H, W, 3) and rgb.dtype == np.float32 and rgb.min() >= 0 and rgb.max() <= 1
    assert model.encode_image(np.full((H, W, 3), 0.5, np.float32)).shape == (4, H // 8, W // 8)
    with pytest.raises(ValueError, match="lcm"):
        model.predict_v(torch.randn(3, 4, H // 8, W // 8), torch.tensor(1), _window(model, cond, text), lcm=True)


def test_encode_frames_layout_dropped_channels_and_masks(model):
    amr = np.zeros((H, W), np.float32)
    amr[:, : W // 2] = 1  # left half masked out
    cond = model.encode_frames([_frame(0), _frame(1, drop=("normal",)), _frame(2, drop=("albedo",)), _frame(3, amr=amr)])
    assert cond[1, 4:8].abs().max() == 0 and cond[1, 0:4].abs().max() > 0  # dropped normal -> zeros in its slot
    assert cond[2, 0:4].abs().max() == 0 and cond[2, 20:24].abs().max() == 0  # no albedo -> no shading prior
    assert cond[0, 20:24].abs().max() > 0
    assert torch.all(cond[:3, 16:19] >= -1) and torch.all(cond[:3, 16:19] <= 1)  # irradiance mapped to [-1, 1]
    assert torch.equal(cond[3, 19, :, : W // 16], torch.ones(H // 8, W // 16))  # union mask, area-downsampled
    assert cond[3, 20:24, :, : W // 16].abs().max() == 0  # shading zero where masked out
    for slot in (0, 8, 12):  # albedo, roughness, metallic latents zero where masked out; normal kept
        assert cond[3, slot : slot + 4, :, : W // 16].abs().max() == 0 and cond[3, slot : slot + 4, :, W // 16 :].abs().max() > 0
    assert cond[3, 4:8, :, : W // 16].abs().max() > 0
    assert cond[3, 20:24, :, W // 16 :].abs().max() > 0
    # pure in its input: same frames, same latents
    assert torch.allclose(model.encode_frames([_frame(0)])[0], cond[0], atol=1e-5)  # batch-size independent


def test_encode_frames_rejects_bad_sizes(model):
    bad = _frame(7)
    bad.channels["albedo"] = np.zeros((H, W + 8, 3), np.float32)
    with pytest.raises(ValueError, match="frame 7.*albedo"):
        model.encode_frames([bad])
    odd = FrameConditioning({}, np.zeros((60, 96), np.float32), np.zeros((0, 60, 96), np.float32), frame_index=4)
    with pytest.raises(ValueError, match="frame 4"):
        model.encode_frames([odd])


def test_alphas_cumprod_is_sd21_zero_terminal_snr(model):
    a = model.alphas_cumprod()
    ref = DDIMScheduler(beta_start=0.00085, beta_end=0.012, beta_schedule="scaled_linear", rescale_betas_zero_snr=True).alphas_cumprod
    assert a.dtype == torch.float64 and a.shape == (1000,)
    assert a[-1] == 0 and torch.all(a[1:] <= a[:-1])
    assert torch.allclose(a.float(), ref, atol=1e-6)


def test_windows_in_one_batch_equal_separate_calls(model):
    procs = hybrid_processors(model.unet)
    g = torch.Generator().manual_seed(0)
    x, cond, ref = torch.randn(6, 4, 8, 12, generator=g), torch.randn(6, 24, 8, 12, generator=g), torch.randn(6, 4, 8, 12, generator=g)
    text = torch.randn(2, 16, 384, generator=g)
    try:
        for p in procs.values():
            p.alpha_r.data.fill_(0.3)
            p.alpha_t.data.fill_(0.3)
        with torch.no_grad():
            both = run_unet(model.unet, x, torch.tensor([100, 800]), cond, ref, num_frames=3, text_global=text, ref_positions=(0, 2), mode="interp", level=1)
            one = [run_unet(model.unet, x[3 * i : 3 * i + 3], t, cond[3 * i : 3 * i + 3], ref[3 * i : 3 * i + 3], num_frames=3,
                            text_global=text[i : i + 1], ref_positions=(0, 2), mode="interp", level=1) for i, t in enumerate((100, 800))]
    finally:
        for p in procs.values():
            p.alpha_r.data.zero_()
            p.alpha_t.data.zero_()
    assert torch.allclose(both, torch.cat(one), atol=1e-5)


def test_image_model_runs_frames_independently():
    img = X2VideoModel.untrained("tiny", video=False, shading_prior=False)
    assert img.unet.config.in_channels == 23
    cond = torch.randn(3, 20, 8, 12)
    x = torch.randn(3, 4, 8, 12)
    x2 = x.clone()
    x2[2] += 1
    text = torch.randn(1, 32, 384)
    a = img.predict_v(x, torch.tensor(500), _window(img, cond, text))
    b = img.predict_v(x2, torch.tensor(500), _window(img, cond, text))
    assert torch.equal(a[:2], b[:2]) and not torch.equal(a[2], b[2])
    video = img.to_video(shading_prior=True)
    assert video.unet.config.in_channels == 32 and video.config.video
    cond32 = torch.cat([cond, torch.randn(3, 4, 8, 12)], 1)
    assert (video.predict_v(x, torch.tensor(500), _window(video, cond32, text)) - a).abs().max() <= 1e-5


def test_checkpoint_round_trip(model, tmp_path):
    model.config.latent_scales["albedo"] = 0.7
    try:
        model.save_pretrained(tmp_path / "ckpt")
        loaded = X2VideoModel.from_pretrained(tmp_path / "ckpt")
    finally:
        model.config.latent_scales["albedo"] = 1.0
    assert loaded.config.latent_scales["albedo"] == 0.7 and loaded.config.shading_prior and not loaded.is_untrained
    for a, b in ((model.unet, loaded.unet), (model.vae, loaded.vae)):
        sa, sb = a.state_dict(), b.state_dict()
        assert sa.keys() == sb.keys() and all(torch.equal(sa[k], sb[k]) for k in sa)
    half = model.save_pretrained(tmp_path / "half", dtype=torch.float16)
    assert (half / "unet.safetensors").stat().st_size < (tmp_path / "ckpt" / "unet.safetensors").stat().st_size * 0.6
    assert X2VideoModel.from_pretrained(half).dtype == torch.float32


def test_checkpoint_mismatch_names_every_tensor(model, tmp_path):
    path = model.save_pretrained(tmp_path / "ckpt")
    data = json.loads((path / "config.json").read_text())
    data["config"]["shading_prior"] = False  # the UNet on disk takes 32 channels, the config now says 28
    data["config"]["hybrid"]["interp_levels"] = 5  # and expects an extra temporal branch per layer
    (path / "config.json").write_text(json.dumps(data))
    with pytest.raises(ValueError) as err:
        X2VideoModel.from_pretrained(path)
    msg = str(err.value)
    assert "conv_in.weight: checkpoint shape (32, 32, 3, 3) != model shape (32, 28, 3, 3)" in msg
    assert "missing tensor down_blocks.1.attentions.0.transformer_blocks.0.attn1.processor.temp.lora.interp5.q.up.weight" in msg
    data["config"]["bogus"] = 1
    (path / "config.json").write_text(json.dumps(data))
    with pytest.raises(ValueError, match="bogus"):
        X2VideoModel.from_pretrained(path)


def test_presets_build_configs():
    for name in ("tiny", "small", "sd21"):
        cfg = preset(name)
        assert ModelConfig.from_dict(json.loads(cfg.to_json())) == cfg
        assert isinstance(cfg.shading_prior, bool)
    assert preset("sd21").unet.cross_attention_dim == 1024 and preset("sd21").vae.downsample == 8
    with pytest.raises(ValueError, match="unknown model preset"):
        preset("huge")


def test_sd21_preset_converts_on_the_meta_device():
    from x2video.model.unet import build_unet, hybrid_processors

    with torch.device("meta"):  # shapes only: no 3.8 GB of weights on a CI machine
        unet = build_unet(preset("sd21"))
    assert unet.config.in_channels == 32 and unet.config.cross_attention_dim == 1024
    procs = hybrid_processors(unet)
    assert len(procs) == 16  # SD 2.1: 16 transformer blocks
    first = procs["down_blocks.0.attentions.0.transformer_blocks.0.attn1.processor"]
    assert first.ref.to_q.weight.shape == (320, 320) and set(first.temp.branches) == {"key", "interp1", "interp2", "interp3", "interp4"}


def test_checkpoint_refuses_tensors_not_finite_in_its_dtype(tmp_path):
    from x2video.model.checkpoint import save_checkpoint

    cfg = preset("tiny")
    with pytest.raises(ValueError, match="unet: tensor w has non-finite values in float16"):
        save_checkpoint(tmp_path / "a", cfg, {"unet": {"w": torch.tensor([1.0, 1e6])}}, dtype=torch.float16)
    with pytest.raises(ValueError, match="vae: tensor b has non-finite values in float32"):
        save_checkpoint(tmp_path / "b", cfg, {"vae": {"b": torch.tensor([float("nan")])}})
    save_checkpoint(tmp_path / "c", cfg, {"unet": {"w": torch.tensor([1.0, 1e6])}})  # fine in float32
    assert (tmp_path / "c" / "unet.safetensors").is_file()


def _zero_residual(model: X2VideoModel):
    """predict_v of a UNet that has learned nothing but 'the residual is zero': x0 = 0 at every step."""
    ac = model.alphas_cumprod().float()

    def predict_v(x_t, t, window, *, lcm=False):
        a = ac[int(t)]
        return (a / (1 - a)).sqrt() * x_t  # v = sqrt(a) eps - sqrt(1-a) x0 with x0 = 0, eps = x_t / sqrt(1-a)

    return predict_v


def test_residual_model_with_zero_residual_renders_the_classical_shading(monkeypatch):
    """A residual-prior model adds the prior's latent to its sample and the VAE-lost detail to the
    decoded frame, so a UNet that predicts a zero residual reproduces the classical shading exactly;
    without the detail it is the VAE's reconstruction of the shading; a dropped channel (no prior)
    leaves the plain decode."""
    from x2video.conditioning.frame import plain_conditioning
    from x2video.model.shading import classical_shading
    from x2video.render.events import FramesReady
    from x2video.render.renderer import Renderer
    from x2video.render.settings import RenderSettings
    from x2video.shot import ArrayShot

    model = X2VideoModel.untrained("tiny", seed=1, residual_prior=True)
    assert model.residual_prior and not X2VideoModel.untrained("tiny", seed=1).residual_prior
    monkeypatch.setattr(model, "predict_v", _zero_residual(model))
    frames = [_frame(i) for i in range(5)]
    shot = ArrayShot({k: np.stack([f.channels[k] for f in frames]) for k in frames[0].channels}, fps=10.0)

    def render(settings, shot=shot):
        out = {}
        Renderer(model).render(shot, None, settings, on_event=lambda e: out.update(e.frames) if isinstance(e, FramesReady) else None)
        return np.stack([out[t] for t in range(shot.num_frames)])

    got = render(RenderSettings(steps=3, window=3))
    want = np.stack([classical_shading(plain_conditioning(shot, t).channels) for t in range(5)])
    np.testing.assert_allclose(got, want, atol=2e-3)  # the Renderer caches the detail in half precision (|detail| <= ~2 here)
    # without the detail: the VAE's reconstruction of the shading, which loses detail
    cond = model.encode_frames([plain_conditioning(shot, t) for t in range(5)])
    smooth = model.decode(cond[:, -4:])
    np.testing.assert_allclose(render(RenderSettings(steps=3, window=3, detail=False)), smooth, atol=1e-4)
    assert float(np.abs(smooth - want).mean()) > 1e-3
    # no irradiance -> no prior: the zero residual decodes the zero latent, no detail is added
    no_irr = ArrayShot({k: np.stack([f.channels[k] for f in frames]) for k in frames[0].channels if k != "irradiance"}, fps=10.0)
    blank = model.decode(torch.zeros(1, 4, H // 8, W // 8))[0]
    np.testing.assert_allclose(render(RenderSettings(steps=2, window=3), no_irr), np.broadcast_to(blank, (5, H, W, 3)), atol=1e-4)


def test_zero_x0_head_renders_the_classical_shading():
    """The real UNet path: an x0-predicting residual model whose output layer is zero (how training
    starts it) renders the classical shading exactly, with DDIM and with LCM."""
    from x2video.conditioning.frame import plain_conditioning
    from x2video.model.shading import classical_shading
    from x2video.render.events import FramesReady
    from x2video.render.renderer import Renderer
    from x2video.render.settings import RenderSettings
    from x2video.shot import ArrayShot
    from x2video.train.diffusion_stages import zero_output_layer

    model = X2VideoModel.untrained("tiny", seed=2, residual_prior=True, prediction="sample")
    zero_output_layer(model.unet)
    model.lcm_unet = model.unet
    frames = [_frame(i) for i in range(3)]
    shot = ArrayShot({k: np.stack([f.channels[k] for f in frames]) for k in frames[0].channels}, fps=10.0)
    want = np.stack([classical_shading(plain_conditioning(shot, t).channels) for t in range(3)])
    for sampler, steps in (("ddim", 4), ("lcm", 2)):
        out = {}
        Renderer(model).render(shot, None, RenderSettings(sampler=sampler, steps=steps, window=3),
                               on_event=lambda e: out.update(e.frames) if isinstance(e, FramesReady) else None)
        np.testing.assert_allclose(np.stack([out[t] for t in range(3)]), want, atol=2e-3)  # detail cached in half precision


def test_x0_prediction_is_converted_to_v():
    """run_unet with prediction="sample" returns the v whose x0 is the UNet's output, at any timestep."""
    from x2video.model.inputs import sd_alphas_cumprod, v_from_sample

    x0, x_t = torch.randn(3, 4, 2, 2), torch.randn(3, 4, 2, 2)
    t = torch.tensor([0, 500, 999])
    v = v_from_sample(x0, x_t, t)
    a = sd_alphas_cumprod().float()[t].view(-1, 1, 1, 1)
    torch.testing.assert_close(a.sqrt() * x_t - (1 - a).sqrt() * v, x0, atol=1e-5, rtol=1e-5)  # x0 from v (DDIM's formula)
    torch.testing.assert_close(v[2], -x0[2])  # zero terminal SNR
    with pytest.raises(ValueError, match="prediction"):
        ModelConfig(prediction="eps")


def test_residual_prior_needs_the_shading_prior():
    m = X2VideoModel.untrained("tiny", seed=1, residual_prior=True, shading_prior=False)
    assert not m.residual_prior  # the flag alone does nothing without the prior's latent
    assert m.detail([_frame(0)], m.encode_frames([_frame(0)])) is None


def test_bf16_encoder_changes_only_the_encoder(model, tmp_path):
    """`encoder_dtype=bfloat16`: the channel latents come back in float32, within bf16 rounding of the
    float32 encoder's; decoding is float32 as before; the conditioning cache key tells the two apart."""
    model.save_pretrained(tmp_path / "m")
    fp32 = X2VideoModel.from_pretrained(tmp_path / "m", text_encoder=model.text_encoder)
    bf16 = X2VideoModel.from_pretrained(tmp_path / "m", text_encoder=model.text_encoder, encoder_dtype=torch.bfloat16)
    assert bf16.vae.encoder.conv_in.weight.dtype == torch.bfloat16 and bf16.vae.decoder.conv_in.weight.dtype == torch.float32
    frames = [_frame(i) for i in range(2)]
    a, b = fp32.encode_frames(frames), bf16.encode_frames(frames)
    assert b.dtype == torch.float32
    err = float((a - b).norm() / a.norm())
    assert 0 < err < 0.02, err  # bf16 keeps 8 bits of mantissa: off, but by little
    z = torch.randn(2, 4, H // 8, W // 8)
    assert np.array_equal(fp32.decode(z), bf16.decode(z))
    assert fp32.content_key() != bf16.content_key()
