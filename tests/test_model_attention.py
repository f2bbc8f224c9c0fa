"""Hybrid Self-Attention and Masked Cross-Attention: equivalence at conversion, MHF routing, reference routing, masks, LoRA switching."""
from __future__ import annotations

import pytest
import torch
from diffusers.models.attention_processor import Attention, AttnProcessor2_0

from x2video.model.config import HybridConfig, preset
from x2video.model.context import AttnContext
from x2video.model.cross_attention import MaskedCrossAttnProcessor
from x2video.model.hybrid_attention import HybridSelfAttnProcessor
from x2video.model.inputs import run_unet
from x2video.model.unet import build_image_unet, convert_image_to_video, hybrid_processors

N, H_LAT, W_LAT = 3, 12, 16  # small latents: 12x16 -> 6x8 -> 3x4 token grids


@pytest.fixture(scope="module")
def unets():
    torch.manual_seed(0)
    cfg = preset("tiny")
    image = build_image_unet(cfg.unet)
    return cfg, image, convert_image_to_video(image, cfg.hybrid, shading_prior=True)


def _inputs(seed: int = 1, frames: int = N):
    g = torch.Generator().manual_seed(seed)
    x = torch.randn(frames, 4, H_LAT, W_LAT, generator=g)
    cond = torch.randn(frames, 24, H_LAT, W_LAT, generator=g)  # intrinsic 19 | mask 1 | shading 4
    ref = torch.randn(frames, 4, H_LAT, W_LAT, generator=g)
    text = torch.randn(1, 8, 384, generator=g)
    return x, cond, ref, text


def test_alphas_zero_video_unet_equals_image_unet_on_every_frame(unets):
    cfg, image, video = unets
    x, cond, ref, text = _inputs()
    local = torch.randn(1, 2, 8, 384)  # two local prompts whose masks are empty
    masks = torch.zeros(N, 2, H_LAT * 8, W_LAT * 8)
    with torch.no_grad():
        expected = run_unet(image, x, 500, cond, None, num_frames=N, text_global=text)
    for mode, positions, level in (("key", (0,), 3), ("interp", (0, N - 1), 1), ("interp", (0, N - 1), 2)):
        # grad enabled: the reference and temporal branches are computed (alpha 0 still gets gradients)
        for grad in (False, True):
            with torch.set_grad_enabled(grad):
                got = run_unet(video, x, 500, cond, ref, num_frames=N, text_global=text, ref_positions=positions,
                               mode=mode, level=level, text_local=local, local_masks=masks)
            assert (got.detach() - expected).abs().max().item() <= 1e-5, (mode, level, grad)


def test_nonzero_alphas_make_frames_interact(unets):
    _, _, video = unets
    x, cond, ref, text = _inputs()
    x2 = x.clone()
    x2[2] += 1.0  # change only frame 2
    procs = hybrid_processors(video)
    try:
        for p in procs.values():
            p.alpha_t.data.fill_(0.3)
        with torch.no_grad():
            a = run_unet(video, x, 500, cond, ref, num_frames=N, text_global=text, ref_positions=(0,))
            b = run_unet(video, x2, 500, cond, ref, num_frames=N, text_global=text, ref_positions=(0,))
    finally:
        for p in procs.values():
            p.alpha_t.data.zero_()
    assert (a[0] - b[0]).abs().max() > 1e-4  # frame 0 now reads frame 2 through the temporal branch


def _attn_layer(heads: int = 4, dim_head: int = 3) -> Attention:
    torch.manual_seed(3)
    c = heads * dim_head
    attn = Attention(query_dim=c, heads=heads, dim_head=dim_head, bias=False)
    with torch.no_grad():  # identity output projection keeps heads apart in the output channels
        attn.to_out[0].weight.copy_(torch.eye(c))
        attn.to_out[0].bias.zero_()
    return attn


def _hybrid(attn: Attention, alpha_r: float, alpha_t: float) -> HybridSelfAttnProcessor:
    proc = HybridSelfAttnProcessor(attn, HybridConfig(lora_rank=2, interp_levels=2))
    with torch.no_grad():
        proc.alpha_r.fill_(alpha_r)
        proc.alpha_t.fill_(alpha_t)
    return proc


@pytest.mark.parametrize("frames,heads", [(5, 4), (3, 4), (4, 4)])
def test_mhf_head_h_of_frame_i_reads_only_frame_i_plus_h_mod_n(frames, heads):
    attn, dim_head, tokens = _attn_layer(heads), 3, 6
    proc = _hybrid(attn, 0.0, 1.0)  # output = TempAttn only
    ctx = AttnContext(num_frames=frames, latent_size=(2, 3))
    c = heads * dim_head

    # crafted values: zero queries give uniform attention, identity values, frame j holds the constant j+1,
    # so head h of frame i must output exactly (i+h) mod N + 1
    with torch.no_grad():
        proc.temp.to_q.weight.zero_()
        proc.temp.to_v.weight.copy_(torch.eye(c))
    x = torch.arange(1, frames + 1, dtype=torch.float32)[:, None, None].expand(frames, tokens, c).contiguous()
    out = proc(attn, x, x2v=ctx).detach().view(frames, tokens, heads, dim_head)
    for i in range(frames):
        for h in range(heads):
            assert torch.allclose(out[i, :, h], torch.full((tokens, dim_head), float((i + h) % frames + 1))), (i, h)

    # random weights: the gradient of head h of frame i reaches frame i (queries) and (i+h) mod N (keys/values) only
    torch.manual_seed(4)
    for lin in (proc.temp.to_q, proc.temp.to_k, proc.temp.to_v):
        torch.nn.init.normal_(lin.weight)
    x = torch.randn(frames, tokens, c, requires_grad=True)
    out = proc(attn, x, x2v=ctx).view(frames, tokens, heads, dim_head)
    for i in range(frames):
        for h in range(heads):
            (g,) = torch.autograd.grad(out[i, :, h].sum(), x, retain_graph=True)
            touched = {j for j in range(frames) if g[j].abs().max() > 0}
            assert touched == {i, (i + h) % frames}, (i, h, touched)


@pytest.mark.parametrize("mode,positions,sources", [("key", (0,), {0}), ("interp", (0, 3), {0, 3}), ("key", (), {0})])
def test_reference_attention_reads_only_reference_frames(mode, positions, sources):
    frames, heads, dim_head = 4, 2, 3
    attn = _attn_layer(heads, dim_head)
    proc = _hybrid(attn, 1.0, 0.0)  # output = RefAttn only
    ctx = AttnContext(num_frames=frames, latent_size=(2, 2), ref_positions=positions, mode=mode, level=1)
    x = torch.randn(2 * frames, 4, heads * dim_head, requires_grad=True)  # two windows
    out = proc(attn, x, x2v=ctx)
    for w in range(2):
        for i in range(frames):
            (g,) = torch.autograd.grad(out[w * frames + i].sum(), x, retain_graph=True)
            touched = {j for j in range(2 * frames) if g[j].abs().max() > 0}
            assert touched == {w * frames + i} | {w * frames + s for s in sources}, (w, i, touched)


def test_masked_cross_attention_without_local_prompts_is_plain_cross_attention():
    torch.manual_seed(5)
    attn = Attention(query_dim=16, cross_attention_dim=10, heads=4, dim_head=4)
    x, text = torch.randn(2 * 3, 12, 16), torch.randn(6, 7, 10)
    plain = AttnProcessor2_0()(attn, x, encoder_hidden_states=text)
    proc = MaskedCrossAttnProcessor()
    assert torch.allclose(proc(attn, x, encoder_hidden_states=text), plain, atol=1e-6)
    for ctx in (
        AttnContext(num_frames=3, latent_size=(3, 4)),
        AttnContext(num_frames=3, latent_size=(3, 4), text_local=torch.zeros(2, 0, 7, 10), local_masks=torch.zeros(6, 0, 24, 32)),
    ):
        assert torch.allclose(proc(attn, x, encoder_hidden_states=text, x2v=ctx), plain, atol=1e-6)


def test_local_prompt_changes_features_only_inside_its_resized_mask():
    torch.manual_seed(6)
    attn = Attention(query_dim=16, cross_attention_dim=10, heads=4, dim_head=4)
    frames, gh, gw = 2, 5, 4  # layer grid of a 10x7 latent one level down (ceil halving)
    x, text = torch.randn(frames, gh * gw, 16), torch.randn(frames, 7, 10)
    proc = MaskedCrossAttnProcessor()
    base = proc(attn, x, encoder_hidden_states=text, x2v=AttnContext(num_frames=frames, latent_size=(10, 7)))
    mask = torch.zeros(frames, 1, 80, 56)  # pixel masks at f=8
    mask[0, 0, :20, :20] = 1.0  # frame 0: top-left corner
    mask[1, 0, 50:, 30:] = 0.5  # frame 1: a soft bottom-right region
    ctx = AttnContext(num_frames=frames, latent_size=(10, 7), text_local=torch.randn(1, 1, 7, 10), local_masks=mask)
    out = proc(attn, x, encoder_hidden_states=text, x2v=ctx)
    resized = torch.nn.functional.interpolate(mask, size=(gh, gw), mode="area").flatten(2)[:, 0]  # (frames, 20)
    changed = (out - base).abs().amax(-1) > 1e-6  # (frames, 20)
    assert changed.any()
    assert torch.equal(changed, resized > 0)


def test_local_prompts_batched_equal_one_at_a_time():
    torch.manual_seed(7)
    attn = Attention(query_dim=16, cross_attention_dim=10, heads=4, dim_head=4)
    p, frames = 9, 2
    x, text = torch.randn(frames, 12, 16), torch.randn(frames, 7, 10)
    local, masks = torch.randn(1, p, 7, 10), torch.rand(frames, p, 3, 4)
    proc = MaskedCrossAttnProcessor()
    ctx = lambda tl, m: AttnContext(num_frames=frames, latent_size=(3, 4), text_local=tl, local_masks=m)  # noqa: E731
    base = proc(attn, x, encoder_hidden_states=text, x2v=ctx(local[:, :0], masks[:, :0]))
    all_at_once = proc(attn, x, encoder_hidden_states=text, x2v=ctx(local, masks))
    summed = base + sum(proc(attn, x, encoder_hidden_states=text, x2v=ctx(local[:, i : i + 1], masks[:, i : i + 1])) - base for i in range(p))
    assert torch.allclose(all_at_once, summed, atol=1e-5)


def test_lora_switch_changes_outputs_only_where_the_branch_is_used(unets):
    _, _, video = unets
    x, cond, ref, text = _inputs(seed=8, frames=3)
    procs = hybrid_processors(video)
    calls = {
        "key": dict(mode="key", level=3, ref_positions=(0,)),
        "interp1": dict(mode="interp", level=1, ref_positions=(0, 2)),
        "interp2": dict(mode="interp", level=2, ref_positions=(0, 2)),
        "interp9": dict(mode="interp", level=9, ref_positions=(0, 2)),  # clamps to the deepest branch
    }

    def run_all():
        with torch.no_grad():
            return {k: run_unet(video, x, 700, cond, ref, num_frames=3, text_global=text, **kw) for k, kw in calls.items()}

    deepest = f"interp{next(iter(procs.values())).interp_levels}"
    try:
        for p in procs.values():
            p.alpha_r.data.fill_(0.2)
            p.alpha_t.data.fill_(0.2)
        before = run_all()
        g = torch.Generator().manual_seed(9)
        for p in procs.values():  # perturb the temporal branch of interpolation level 2 only
            for lora in p.temp.lora["interp2"].values():
                lora.up.weight.data.normal_(0, 0.5, generator=g)
        after = run_all()
        used_by = {"key": False, "interp1": False, "interp2": True, "interp9": deepest == "interp2"}
        for k, used in used_by.items():
            assert ((after[k] - before[k]).abs().max() > 1e-5) == used, k
        for p in procs.values():  # the end-frame reference branch r1 is used only when interpolating
            for lora in p.ref.lora["r1"].values():
                lora.up.weight.data.normal_(0, 0.5, generator=g)
        after_r1 = run_all()
        for k in calls:
            assert ((after_r1[k] - after[k]).abs().max() > 1e-5) == (k != "key"), k
    finally:
        for p in procs.values():
            p.alpha_r.data.zero_()
            p.alpha_t.data.zero_()
            for branches in (p.temp.lora, p.ref.lora):
                for lora3 in branches.values():
                    for lora in lora3.values():
                        lora.up.weight.data.zero_()


def test_context_grid_follows_ceil_halving():
    ctx = AttnContext(num_frames=1, latent_size=(7, 5))
    assert ctx.grid(35) == (7, 5)
    assert ctx.grid(12) == (4, 3)
    assert ctx.grid(4) == (2, 2)
    with pytest.raises(ValueError):
        ctx.grid(10)


@pytest.mark.parametrize("frames,heads", [(5, 5), (3, 8), (9, 5), (1, 4), (17, 20)])
def test_mhf_gather_matches_its_definition(frames, heads):
    from x2video.model.hybrid_attention import mhf_gather

    x = torch.randn(2 * frames, 7, heads * 3)  # two windows
    out = mhf_gather(x, frames, heads).view(2, frames, heads, 7, 3)
    src = x.view(2, frames, 7, heads, 3)
    for i in range(frames):
        for h in range(heads):
            assert torch.equal(out[:, i, h], src[:, (i + h) % frames, :, h]), (i, h)


def test_image_unet_with_shading_prior_converts_exactly():
    """A 27-input image UNet (XRGB 23 + shading 4): its shading weights move behind reference and
    mask, so the converted video UNet (alphas 0) reproduces it on every frame, shading included."""
    torch.manual_seed(3)
    cfg = preset("tiny")
    image = build_image_unet(cfg.unet, shading_prior=True)
    assert image.config.in_channels == 27
    with torch.no_grad():
        image.conv_in.weight.normal_()  # make the shading weights non-trivial
    video = convert_image_to_video(image, cfg.hybrid, shading_prior=True)
    assert video.config.in_channels == 32
    x, cond, ref, text = _inputs(seed=5)
    with torch.no_grad():
        expected = run_unet(image, x, 300, cond, None, num_frames=N, text_global=text)
        got = run_unet(video, x, 300, cond, ref, num_frames=N, text_global=text, ref_positions=(0,), mode="key", level=1)
        cond_other = cond.clone()
        cond_other[:, -4:] += 1.0  # the shading latent is an input of both
        moved = run_unet(image, x, 300, cond_other, None, num_frames=N, text_global=text)
    assert (got - expected).abs().max().item() <= 1e-4
    assert (moved - expected).abs().max().item() > 1e-3
    with pytest.raises(ValueError, match="shading prior on"):
        convert_image_to_video(image, cfg.hybrid, shading_prior=False)
