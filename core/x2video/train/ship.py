"""Ship a trained model: the newest model of a run, in fp16, as the folder `resources/` holds.

    OUT/config.json, unet.safetensors, vae.safetensors[, lcm_unet.safetensors]   (fp16)
    OUT/image/...        optional: the image-stage model (eval table a)
    OUT/training.json    {"size": [W, H], "shipped": {part: {source, bytes}}, "runs": {name: {summary, results}},
                          "previous": [the "shipped" records of the folders this one replaced, newest first]}

`training.json`'s size is what `x2video eval` and the renderers read to know the resolution the
model was trained at. The folder is assembled beside OUT and renamed into place, so an
interrupted ship never leaves a half-written model where the CLI and editor look for one.

A model continued from the shipped one (`--init resources/...`) descends from runs whose folders may
be gone; `keep_runs` carries the replaced folder's run records and shipped sources into the new
training.json, so the lineage the model card describes stays on record beside the weights.
"""
from __future__ import annotations

import json
import shutil
import tempfile
from pathlib import Path
from typing import Any

import torch
from safetensors.torch import load_file

from x2video.eval.data import training_size
from x2video.io.paths import portable_path
from x2video.model.checkpoint import PARTS, read_config, save_checkpoint
from x2video.train.runs import model_dir


def _copy_fp16(src: Path, dst: Path) -> dict[str, Any]:
    """The checkpoint folder `src` rewritten in fp16 into `dst` (through `save_checkpoint`, which
    refuses tensors that are not finite in fp16)."""
    parts = {p: load_file(str(src / f"{p}.safetensors")) for p in PARTS if (src / f"{p}.safetensors").is_file()}
    if "unet" not in parts or "vae" not in parts:
        raise FileNotFoundError(f"{src}: a shippable model needs unet.safetensors and vae.safetensors")
    save_checkpoint(dst, read_config(src), parts, dtype=torch.float16)
    return {"source": portable_path(src.resolve()), "bytes": {p: (dst / f"{p}.safetensors").stat().st_size for p in parts}}


def _run_doc(run: Path) -> dict[str, Any]:
    doc: dict[str, Any] = {"path": portable_path(run)}
    for name in ("summary.json", "results.json"):
        f = run / name
        if f.is_file():
            doc[name.removesuffix(".json")] = json.loads(f.read_text())
    return doc


def ship(model: str | Path, out: str | Path, *, image: str | Path | None = None, size: tuple[int, int] | None = None,
         runs: list[Path] | None = None, overwrite: bool = False, keep_runs: bool = False) -> dict[str, Any]:
    out = Path(out)
    if out.exists() and not overwrite:
        raise FileExistsError(f"{out} exists; pass --overwrite to replace it")
    kept: dict[str, Any] = {}
    if keep_runs:
        old_doc = out / "training.json"
        if not old_doc.is_file():
            raise FileNotFoundError(f"{old_doc}: --keep-runs needs the training.json of the folder being replaced")
        try:
            kept = json.loads(old_doc.read_text())
        except ValueError as e:
            raise ValueError(f"{old_doc}: cannot read JSON ({e})") from None
        if not isinstance(kept.get("runs"), dict) or not isinstance(kept.get("shipped"), dict):
            raise ValueError(f"{old_doc}: no 'runs' and 'shipped' records to keep")
    src = model_dir(model)
    size = size or training_size(src)
    if size is None:
        raise ValueError(f"{src}: training size unknown (its latent cache is gone); pass --size WxH")
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", dir=out.parent))
    try:
        info = {"model": _copy_fp16(src, tmp)}
        if image is not None:
            info["image"] = _copy_fp16(model_dir(image), tmp / "image")
        doc: dict[str, Any] = {"size": [int(size[0]), int(size[1])], "shipped": info,
                               "runs": {**kept.get("runs", {}), **{Path(r).name: _run_doc(Path(r)) for r in (runs or [])}}}
        if kept:
            doc["previous"] = [kept["shipped"], *kept.get("previous", [])]
        (tmp / "training.json").write_text(json.dumps(doc, indent=1))
        for p in [tmp, *tmp.rglob("*")]:  # mkdtemp and safetensors leave owner-only modes
            p.chmod(0o755 if p.is_dir() else 0o644)
        if out.exists():
            old = out.with_name(f".{out.name}.old")
            shutil.rmtree(old, ignore_errors=True)
            out.rename(old)
            tmp.rename(out)
            shutil.rmtree(old)
        else:
            tmp.rename(out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    total = sum(v for part in info.values() for v in part["bytes"].values())
    return {"out": str(out), "size": doc["size"], "megabytes": round(total / 2**20, 2), "parts": info}
