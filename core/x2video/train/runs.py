"""Training run folders: find the model a run (or a model folder) holds, write a run's results JSON."""
from __future__ import annotations

from pathlib import Path
from typing import Any

from diffusers import AutoencoderKL

from x2video.io.atomic import write_json_atomic
from x2video.model.checkpoint import load_into, read_config
from x2video.model.config import ModelConfig
from x2video.model.vae import build_vae
from x2video.train.loop import latest_checkpoint

RESULTS = "results.json"


def model_dir(path: str | Path) -> Path:
    """The model folder (config.json + safetensors) of `path`: a model folder itself, or a
    training run whose newest `step-*/model/` is used."""
    p = Path(path)
    if (p / "config.json").is_file():
        return p
    ck = latest_checkpoint(p)
    if ck is not None and (ck / "model" / "config.json").is_file():
        return ck / "model"
    if not p.exists():
        raise FileNotFoundError(f"{p}: no such run or model folder")
    raise FileNotFoundError(f"{p}: neither a model folder (config.json) nor a training run with step-*/model/")


def load_vae(path: str | Path) -> tuple[ModelConfig, AutoencoderKL]:
    """The config and frozen VAE of a VAE run, a cache's model/ folder or a full model folder."""
    d = model_dir(path)
    cfg = read_config(d)
    vae = build_vae(cfg.vae)
    load_into(vae, d / "vae.safetensors", "vae")
    return cfg, vae.eval().requires_grad_(False)


def check_same_vae(cfg: ModelConfig, cache_cfg: ModelConfig, where: str) -> None:
    """A model trained on one cache's latents cannot be trained further on another VAE's latents."""
    if cfg.vae != cache_cfg.vae or cfg.latent_scales != cache_cfg.latent_scales:
        raise ValueError(f"{where} was trained on latents of another VAE than this cache's (VAE config or latent scales differ)")


def write_results(run_dir: str | Path, key: str, value: Any) -> Path:
    """Merge `{key: value}` into the run's results.json (atomic write; only the main process writes)."""
    import json

    from x2video.train.loop import process_index

    if process_index() != 0:
        return Path(run_dir) / RESULTS

    path = Path(run_dir) / RESULTS
    data = json.loads(path.read_text()) if path.is_file() else {}
    data[key] = value
    write_json_atomic(path, data)
    return path
