"""Build the two payloads research/gpu/run.sh reads (default .gpu/A and .gpu/B), each small enough for one
64 MiB call with the repository's tracked files (blank resources/*.safetensors first; `git checkout --
resources/` restores them).

    python research/gpu/payload.py --cache RUNS/cache --init RUNS/image_x0/step-000000505/model \
        --wheels GPU/whl --out .gpu

A: the diffusers wheel, the image model to start from (fp16), the cache's model/ (VAE fp16), meta.json,
text embeddings (xz), the whole test split and the train split's albedo/normal/roughness. B: the rest of
the train split. Latents are 8-bit per channel (pack.py; 56.9 dB decoded-RGB PSNR against the fp16 ones).
"""
from __future__ import annotations

import argparse
import lzma
import shutil
import sys
from pathlib import Path

import torch
from safetensors.torch import load_file

from x2video.model.checkpoint import PARTS, read_config, save_checkpoint

sys.path.insert(0, str(Path(__file__).parent))
from pack import pack  # noqa: E402

A_TRAIN = ("albedo", "normal", "roughness")


def fp16_copy(src: Path, dst: Path) -> None:
    """A model folder (config + whichever parts it has, e.g. the cache's VAE alone) in fp16."""
    parts = {p: load_file(str(src / f"{p}.safetensors")) for p in PARTS if (src / f"{p}.safetensors").is_file()}
    save_checkpoint(dst, read_config(src), parts, dtype=torch.float16)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cache", type=Path, required=True)
    ap.add_argument("--init", type=Path, default=None, help="model folder the video stage starts from (carried as stash/init); "
                    "leave it out when it travels anyway, e.g. the shipped resources/x2video-tiny (run.sh's INIT)")
    ap.add_argument("--wheels", type=Path, required=True, help="folder of wheels the device image lacks (diffusers)")
    ap.add_argument("--out", type=Path, default=Path(".gpu"))
    a = ap.parse_args()
    packed = a.out / "packed"
    pack(a.cache, "train", packed)
    pack(a.cache, "test", packed)
    A, B = a.out / "A" / "stash", a.out / "B" / "stash"
    for d in (A, B):
        shutil.rmtree(d, ignore_errors=True)
        d.mkdir(parents=True)
    for w in a.wheels.glob("*.whl"):
        shutil.copy(w, a.out / "A" / w.name)
    if a.init is not None:
        fp16_copy(a.init, A / "init")
    fp16_copy(a.cache / "model", A / "model")
    shutil.copy(a.cache / "meta.json", A / "meta.json")
    (A / "text.safetensors.xz").write_bytes(lzma.compress((a.cache / "text.safetensors").read_bytes()))
    for f in packed.iterdir():
        split, key = f.name.split(".")[:2]
        to_a = split == "test" or key in A_TRAIN or key == "meta"
        shutil.move(str(f), (A if to_a else B) / f.name)
    shutil.rmtree(packed)
    for d in (a.out / "A", a.out / "B"):
        print(d, round(sum(f.stat().st_size for f in d.rglob("*") if f.is_file()) / 2**20, 1), "MiB")


if __name__ == "__main__":
    main()
