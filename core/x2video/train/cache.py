"""The latent cache: every frame of the train/test rooms VAE-encoded ONCE, so diffusion training is pure tensor indexing.

The VAE is frozen during diffusion training (paper Sec. Implementation via XRGB), so the
posterior-mode latents of albedo, normal, roughness, metallic, the rgb target and the
shading prior never change. One pass writes:

    CACHE/model/        config.json (VAE config, measured latent scales, text config) + vae.safetensors
    CACHE/train.safetensors, CACHE/test.safetensors   per split, F frames of all its rooms:
        albedo normal roughness metallic rgb   (F, 4, h, w) float16, UNSCALED posterior mode
        shading_SM                             (F, 4, h, w) float16, classical shading latent with the
                                               specular term (S: normal+roughness kept) and metallic (M) on/off
        irradiance                             (F, 3, h, w) float16, [-1, 1], area-downsampled
        ids                                    (F, H, W) int16 object ids at pixel resolution (masks)
        room, frame                            (F,) int32: which room and frame each row is
    CACHE/text.safetensors   emb (U, L, D) float16 token embeddings of every caption ("" included)
    CACHE/meta.json          sizes, rooms (name, split, start row, frames, caption, objects), prompts

Because a dropped channel can change the shading prior (no albedo/irradiance: none; no
normal or roughness: no specular; no metallic: metallic 0), all four variants are cached,
so training sees exactly what `X2VideoModel.encode_frames` computes at inference.
"""
from __future__ import annotations

import dataclasses
import json
import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Sequence

import numpy as np
import torch
from diffusers import AutoencoderKL
from safetensors.torch import load_file, save_file

from x2video.channels import INTRINSIC
from x2video.io.atomic import atomic_path, write_json_atomic
from x2video.model.checkpoint import save_checkpoint
from x2video.model.config import LATENT_SCALE_KEYS, ModelConfig
from x2video.model.residual_engine import weights_sha
from x2video.model.shading import classical_shading
from x2video.model.text import TextEncoder, build_text_encoder
from x2video.model.vae import area_downsample, encode_mode, images_to_tensor, irradiance_to_unit, measure_latent_scales, to_vae_range
from x2video.shot import Shot
from x2video.train.data import read_frame

log = logging.getLogger(__name__)

VAE_KEYS = LATENT_SCALE_KEYS
#: shading prior variants: "shading_<S><M>", S = specular term present, M = metallic present
SHADING_KEYS = ("shading_11", "shading_10", "shading_01", "shading_00")
#: tier-1 prior variants (`ModelConfig.prior` "tier1"): "tier1_<N><R><M>", tier 1's frame with normal, roughness and
#: metallic present (1) or dropped (0); albedo and irradiance are always present (without them there is no prior)
TIER1_KEYS = tuple(f"tier1_{n}{r}{m}" for n in (1, 0) for r in (1, 0) for m in (1, 0))
PRIOR_KEYS = {"shading": SHADING_KEYS, "tier1": TIER1_KEYS}
READ = (*INTRINSIC, "rgb", "ids")
FORMAT = "x2video-latent-cache"


def shading_key(specular: bool, metallic: bool) -> str:
    return f"shading_{int(specular)}{int(metallic)}"


def prior_key(prior: str, keep: dict[str, bool]) -> str | None:
    """The cache key of the prior a sample with these kept channels sees, or None (albedo or irradiance dropped: no prior)."""
    if not (keep["albedo"] and keep["irradiance"]):
        return None
    if prior == "tier1":
        return f"tier1_{int(keep['normal'])}{int(keep['roughness'])}{int(keep['metallic'])}"
    return shading_key(keep["normal"] and keep["roughness"], keep["metallic"])


@dataclass
class CacheInfo:
    """meta.json of a cache."""

    size: tuple[int, int]
    """(width, height) of the encoded frames."""
    latent_size: tuple[int, int]
    """(h, w) of the latents."""
    rooms: list[dict]
    prompts: list[str]
    format: str = FORMAT
    prior: str = "shading"
    """What the prior latents hold (`ModelConfig.prior`): "shading" (SHADING_KEYS) or "tier1" (TIER1_KEYS)."""
    prior_net: str = ""
    """With the tier-1 prior: sha256 of the tier-1 net's weights that made it (a model trained on this cache renders
    over that net's frames)."""


def _shading_images(fr: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    out = {}
    for s in (True, False):
        for m in (True, False):
            ch = {"albedo": fr["albedo"], "irradiance": fr["irradiance"],
                  "normal": fr["normal"] if s else None, "roughness": fr["roughness"] if s else None,
                  "metallic": fr["metallic"] if m else None}
            out[shading_key(s, m)] = to_vae_range("shading", classical_shading(ch))
    return out


def _tier1_images(frames: list[dict[str, np.ndarray]], net) -> list[dict[str, np.ndarray]]:
    """Per frame, tier 1's frame (as `Renderer` renders it by default, `residual_frames`) of each TIER1_KEYS variant, in
    the VAE's range: what `X2VideoModel.encode_frames` encodes for a "tier1" model with those channels kept."""
    from x2video.conditioning.frame import FrameConditioning
    from x2video.tiers.residual import residual_frames

    conds, keys = [], []
    for i, fr in enumerate(frames):
        h, w = fr["albedo"].shape[:2]
        for key in TIER1_KEYS:
            n, r, m = (c == "1" for c in key[-3:])
            ch = {"albedo": fr["albedo"], "irradiance": fr["irradiance"], "normal": fr["normal"] if n else None,
                  "roughness": fr["roughness"] if r else None, "metallic": fr["metallic"] if m else None}
            conds.append(FrameConditioning(ch, np.zeros((h, w), np.float32), np.zeros((0, h, w), np.float32), frame_index=i))
            keys.append((i, key))
    out: list[dict[str, np.ndarray]] = [{} for _ in frames]
    for (i, key), img in zip(keys, residual_frames(net, conds, next(net.parameters()).device, batch=8)):
        out[i][key] = to_vae_range("shading", img)
    return out


@torch.no_grad()
def encode_room(vae: AutoencoderKL, shot: Shot, size: tuple[int, int] | None, batch: int = 8, prior_net=None) -> dict[str, torch.Tensor]:
    """All frames of one room -> the per-split tensors above (unscaled latents), frame by frame in chunks; the
    classical shading variants, or with `prior_net` (a tier-1 net) tier 1's frames (TIER1_KEYS). The rgb target is
    brought into the units the channels are read in (times the shot's irradiance normalisation), as the
    renderer's output is before it is divided back into the input's units."""
    dev = next(vae.parameters()).device
    dtype = next(vae.parameters()).dtype
    f = 2 ** (len(vae.config.block_out_channels) - 1)
    parts: dict[str, list[torch.Tensor]] = {}
    for t0 in range(0, shot.num_frames, batch):
        frames = [read_frame(shot, t, READ, size) for t in range(t0, min(shot.num_frames, t0 + batch))]
        for fr in frames:
            fr["rgb"] = (np.asarray(fr["rgb"], np.float32) * np.float32(shot.info.irradiance_scale)).astype(np.float32)
        H, W = frames[0]["rgb"].shape[:2]
        if H % f or W % f:
            raise ValueError(f"shot {shot.info.source!r}: frame size {W}x{H} is not a multiple of the VAE factor {f}; pass --size")
        imgs = {k: [to_vae_range(k, fr[k]) for fr in frames] for k in VAE_KEYS}
        shade = _tier1_images(frames, prior_net) if prior_net is not None else [_shading_images(fr) for fr in frames]
        prior_keys = TIER1_KEYS if prior_net is not None else SHADING_KEYS
        imgs.update({k: [s[k] for s in shade] for k in prior_keys})
        # Encode each distinct image once: a frame without metal has identical metallic on/off
        # shading variants (identical images give identical posterior modes).
        flat = [(k, i) for k in imgs for i in range(len(frames))]
        unique: list[np.ndarray] = []
        slot: dict[tuple[str, int], int] = {}
        for k, i in flat:
            img = imgs[k][i]
            same = next((slot[(k2, i)] for k2 in prior_keys if k in prior_keys and (k2, i) in slot
                         and np.array_equal(unique[slot[(k2, i)]], img)), None)
            if same is None:
                unique.append(img)
                same = len(unique) - 1
            slot[(k, i)] = same
        z_all = encode_mode(vae, images_to_tensor(unique, dev, dtype), batch).to("cpu", torch.float16)  # (U, 4, h, w)
        for k in imgs:
            parts.setdefault(k, []).append(z_all[[slot[(k, i)] for i in range(len(frames))]])
        irr = images_to_tensor([irradiance_to_unit(fr["irradiance"]) for fr in frames], torch.device("cpu"), torch.float32)
        parts.setdefault("irradiance", []).append(area_downsample(irr, (H // f, W // f)).to(torch.float16))  # (n, 3, h, w)
        ids = np.stack([fr["ids"][..., 0] for fr in frames])  # (n, H, W)
        if ids.max(initial=0) > np.iinfo(np.int16).max or ids.min(initial=0) < 0:
            raise ValueError(f"shot {shot.info.source!r}: object ids outside 0..32767")
        parts.setdefault("ids", []).append(torch.from_numpy(ids.astype(np.int16)))
    return {k: torch.cat(v) for k, v in parts.items()}


def _scale_samples(shots: Sequence[Shot], size: tuple[int, int] | None, n: int, seed: int) -> dict[str, list[np.ndarray]]:
    rng = np.random.default_rng(seed)
    picks = [(s, int(rng.integers(s.num_frames))) for s in (shots[i] for i in rng.integers(len(shots), size=n))]
    out: dict[str, list[np.ndarray]] = {k: [] for k in VAE_KEYS}
    for shot, t in picks:
        fr = read_frame(shot, t, VAE_KEYS, size)
        for k in VAE_KEYS:
            out[k].append(fr[k])
    return out


def build_cache(
    shots: dict[str, Sequence[Shot]],
    vae: AutoencoderKL,
    config: ModelConfig,
    out_dir: str | Path,
    *,
    size: tuple[int, int] | None = None,
    text_encoder: TextEncoder | None = None,
    scale_frames: int = 32,
    batch: int = 8,
    progress: Callable[[int, int], None] | None = None,
    prior_net=None,
) -> CacheInfo:
    """Encode every frame of `shots` ({'train': [...], 'test': [...]}) once into `out_dir` (see module doc).
    Latent scales are measured on `scale_frames` random training frames (`measure_latent_scales`) when
    `config` has none (all 1.0, as a VAE run's); a model folder's scales are kept, so the models trained
    with them can train further on this cache (the latents are stored unscaled either way).
    With `prior_net` (a tier-1 net, `x2video.model.residual`) the prior latents are tier 1's frames (TIER1_KEYS, for a
    model whose `ModelConfig.prior` is "tier1") instead of the classical shading."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    train = list(shots.get("train", []))
    if not train:
        raise ValueError("build_cache: no training rooms")
    vae = vae.eval().requires_grad_(False)
    if all(v == 1.0 for v in config.latent_scales.values()):
        scales = measure_latent_scales(vae, _scale_samples(train, size, scale_frames, 0), next(vae.parameters()).device)
        log.info("latent scales (measured): %s", {k: round(v, 4) for k, v in scales.items()})
    else:
        scales = dict(config.latent_scales)
        log.info("latent scales (the VAE folder's): %s", {k: round(v, 4) for k, v in scales.items()})
    cfg = dataclasses.replace(config, latent_scales=scales)

    rooms: list[dict] = []
    prompts: dict[str, None] = {"": None}
    total = sum(s.num_frames for v in shots.values() for s in v)
    done = 0
    latent_size = None
    frame_size = None
    for split, split_shots in shots.items():
        tensors: dict[str, list[torch.Tensor]] = {}
        row = 0
        for i, shot in enumerate(split_shots):
            enc = encode_room(vae, shot, size, batch, prior_net)
            latent_size = tuple(enc["rgb"].shape[-2:])
            frame_size = (int(enc["ids"].shape[-1]), int(enc["ids"].shape[-2]))
            n = enc["rgb"].shape[0]
            enc["room"] = torch.full((n,), len(rooms), dtype=torch.int32)
            enc["frame"] = torch.arange(n, dtype=torch.int32)
            for k, v in enc.items():
                tensors.setdefault(k, []).append(v)
            objects = {str(k): str(v) for k, v in shot.info.object_captions.items()}
            rooms.append({"name": Path(shot.info.source).name or f"{split}-{i}", "source": shot.info.source, "split": split,
                          "start": row, "num_frames": n, "caption": shot.info.caption, "objects": objects})
            prompts.update({shot.info.caption: None, **{c: None for c in objects.values()}})
            row += n
            done += n
            if progress is not None:
                progress(done, total)
        if tensors:
            with atomic_path(out / f"{split}.safetensors") as tmp:
                save_file({k: torch.cat(v).contiguous() for k, v in tensors.items()}, str(tmp), metadata={"format": FORMAT})

    enc_text = text_encoder or build_text_encoder(cfg.text.kind, cfg.text.max_length, cfg.unet.cross_attention_dim, cfg.text.path)
    prompt_list = list(prompts)
    emb = enc_text.encode(prompt_list).to(torch.float16)  # (U, L, D)
    with atomic_path(out / "text.safetensors") as tmp:
        save_file({"emb": emb.contiguous()}, str(tmp), metadata={"format": FORMAT})
    save_checkpoint(out / "model", cfg, {"vae": vae})
    assert latent_size is not None and frame_size is not None
    info = CacheInfo(size=frame_size, latent_size=latent_size, rooms=rooms, prompts=prompt_list,
                     prior="tier1" if prior_net is not None else "shading", prior_net=weights_sha(prior_net) if prior_net is not None else "")
    write_json_atomic(out / "meta.json", dataclasses.asdict(info))
    return info


def read_info(cache_dir: str | Path) -> CacheInfo:
    path = Path(cache_dir) / "meta.json"
    if not path.is_file():
        raise FileNotFoundError(f"{cache_dir}: not a latent cache (no meta.json); build one with `x2video train cache`")
    d = json.loads(path.read_text())
    if d.get("format") != FORMAT:
        raise ValueError(f"{path}: format {d.get('format')!r}, expected {FORMAT!r}")
    d["size"], d["latent_size"] = tuple(d["size"]), tuple(d["latent_size"])
    return CacheInfo(**d)


def load_split(cache_dir: str | Path, split: str) -> dict[str, torch.Tensor]:
    """The tensors of one split (see module doc); raises if the split was not cached."""
    path = Path(cache_dir) / f"{split}.safetensors"
    if not path.is_file():
        raise FileNotFoundError(f"{cache_dir}: no {split} split in this cache ({path.name} missing)")
    return load_file(str(path))


def load_text(cache_dir: str | Path) -> torch.Tensor:
    return load_file(str(Path(cache_dir) / "text.safetensors"))["emb"]
