"""Table (d)'s speed-up on the lent GPU: DDIM-20 vs LCM-2 back to back, with and without the reference frame,
the same loop as `bench.lcm_speedup` (`back_to_back`), on the shots of a `speed_payload.py` payload.

Runs there without OpenImageIO (the shots come from the payload's npz) and without the MiniLM text encoder
(the payload's prompt embeddings stand in for it; any other prompt fails clearly). diffusers must be
importable (install the payload's wheel first; research/gpu/README.md).

    python research/gpu/speed.py --payload .gpu/S [--device cuda] [--repeats 3] [--out $OUT/lcm_speedup_gpu.json]

Writes a `bench.lcm_speedup` result file (format "x2video-lcm-speedup"), which the model card reads.
"""
from __future__ import annotations

import argparse
import json
import shlex
import sys
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))  # the repository root: the bench package (the GPU machine has no install)
from bench.common import result_header  # noqa: E402
from bench.lcm_speedup import back_to_back  # noqa: E402

from x2video.render.settings import RenderSettings  # noqa: E402  (light: no torch)


class PayloadPrompts:
    """A `TextEncoder` that knows only the prompts whose embeddings the payload carries."""

    def __init__(self, table: dict[str, torch.Tensor]) -> None:
        self.table = table

    def encode(self, prompts):
        missing = [p for p in prompts if p not in self.table]
        if missing:
            raise KeyError(f"prompt(s) {missing} have no embedding in the payload (it carries {sorted(self.table)})")
        if not prompts:
            d = next(iter(self.table.values()))
            return d.new_zeros((0, *d.shape[1:]))
        return torch.cat([self.table[p] for p in prompts])


def payload_shots(payload: Path) -> list:
    from x2video.eval.data import EvalShot
    from x2video.shot import ArrayShot

    meta = json.loads((payload / "meta.json").read_text())
    arrays = np.load(payload / "shots.npz")
    shots = []
    for name in meta["rooms"]:
        chans = {k.split("/", 1)[1]: arrays[k].astype(np.float32) for k in arrays.files if k.startswith(name + "/")}
        shots.append(EvalShot(name, payload / name, ArrayShot(chans, source=f"{payload}/shots.npz:{name}"), None))
    return shots


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--payload", type=Path, required=True)
    p.add_argument("--weights", type=Path, default=ROOT / "resources" / "x2video-tiny")
    p.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--steps", type=int, default=20)
    p.add_argument("--lcm-steps", type=int, default=2)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--window", type=int, default=5)
    p.add_argument("--replace-refs", action=argparse.BooleanOptionalAction, default=RenderSettings.replace_refs)
    p.add_argument("--noise", choices=("window", "frame"), default=RenderSettings.noise)
    p.add_argument("--noise-shared", type=float, default=RenderSettings.noise_shared)
    p.add_argument("--ref-dc", type=float, default=RenderSettings.ref_dc)
    p.add_argument("--resample", type=int, default=RenderSettings.resample)
    p.add_argument("--out", type=Path, required=True)
    a = p.parse_args(argv)
    from x2video.eval.runner import EvalModels
    from x2video.io.atomic import write_json_atomic
    from x2video.model.pipeline import X2VideoModel
    from x2video.render.renderer import Renderer

    text = PayloadPrompts(torch.load(a.payload / "prompts.pt"))
    model = X2VideoModel.from_pretrained(a.weights, device=a.device, text_encoder=text)
    if not model.has_lcm:
        raise SystemExit(f"{a.weights} has no lcm_unet.safetensors")
    shots = payload_shots(a.payload)
    meta = json.loads((a.payload / "meta.json").read_text())
    timed = back_to_back({"ddim": Renderer(model), "lcm": Renderer(model)}, shots, a)
    info = {"path": str(a.weights), "config": model.config.name, "video": True, "lcm": True, "untrained": False,
            "note": "lcm_unet.safetensors of --weights"}
    a.data, a.split, a.frames = meta["data"], "test", meta["frames"]  # what result_header records of the data
    result = {**result_header("lcm-speedup", "lcm_speedup", a, EvalModels(model, None, model, {"video": info, "lcm": info}),
                              shots, tuple(meta["size"]), argv), **timed}
    result["command"] = shlex.join(["python", "research/gpu/speed.py", *(sys.argv[1:] if argv is None else argv)])
    result["data"]["payload"] = str(a.payload)
    write_json_atomic(a.out, result)
    for k in ("speedup", "speedup_ref", "speedup_no_encoding"):
        print(f"{k:>20}: median {result['median'][k]:.2f}x (min {result['min'][k]:.2f}, max {result['max'][k]:.2f})")
    print(f"wrote {a.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
