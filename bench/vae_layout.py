"""The VAE encoder in the default (NCHW) and the channels-last (NHWC) memory layout, side by side: milliseconds per
encoded image at the model's training size, and the largest latent difference between the two.

Both samplers pay the channel encoding once per frame (five encodes: albedo, normal, roughness, metallic and the
classical shading), so it is the part of an LCM-2 frame that distillation does not shrink (bench/lcm_speedup.py).
`X2VideoModel` runs the encoder channels-last on the CPU because of this measurement.

    python bench/vae_layout.py [--weights MODEL_DIR] [--size 160x112] [--batch 4] [--repeats 25] [--threads 0] [--bf16]
        [--out bench/results/vae_layout.json]

Each repeat encodes the same random batch once per layout, alternating which goes first, so machine noise lands
on both alike; the medians over repeats (the first 3 dropped as warm-up) and their ratio are reported.
Writes {"format": "x2video-vae-layout", "command", "machine", "weights", "size", "batch", "dtype",
"ms_per_image": {"default", "channels_last"}, "speedup", "max_abs_latent_difference", "latent_std"}.
"""
from __future__ import annotations

import argparse
import copy
import json
import shlex
import statistics
import sys
import time
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "results" / "vae_layout.json"


def measure(args: argparse.Namespace) -> dict:
    import torch

    from x2video.cli.render import shipped_weights
    from x2video.eval.machine import machine_info
    from x2video.model.pipeline import X2VideoModel
    from x2video.train.runs import model_dir

    if args.threads:
        torch.set_num_threads(args.threads)
    weights = args.weights or shipped_weights()
    if weights is None:
        raise SystemExit("vae_layout: no --weights and no shipped weights in resources/")
    model = X2VideoModel.from_pretrained(model_dir(Path(weights)), device="cpu")
    dtype = torch.bfloat16 if args.bf16 else torch.float32
    w, h = args.size
    parts = {}
    for name, fmt in (("default", torch.contiguous_format), ("channels_last", torch.channels_last)):
        enc = copy.deepcopy(model.vae.encoder).to(dtype=dtype, memory_format=fmt).eval()
        quant = copy.deepcopy(model.vae.quant_conv).to(dtype=dtype, memory_format=fmt).eval()
        parts[name] = (enc, quant, fmt)
    gen = torch.Generator().manual_seed(0)
    x = torch.rand(args.batch, 3, h, w, generator=gen).mul(2).sub(1).to(dtype)  # (B, 3, H, W) in [-1, 1]
    times: dict[str, list[float]] = {k: [] for k in parts}
    out: dict[str, torch.Tensor] = {}
    with torch.inference_mode():
        for i in range(args.repeats):
            order = list(parts) if i % 2 == 0 else list(reversed(parts))
            for name in order:
                enc, quant, fmt = parts[name]
                xx = x.contiguous(memory_format=fmt)
                t0 = time.perf_counter()
                z = quant(enc(xx))
                times[name].append((time.perf_counter() - t0) / args.batch * 1000)
                out[name] = z.float()
    med = {k: statistics.median(v[3:]) for k, v in times.items()}
    return {
        "format": "x2video-vae-layout",
        "command": shlex.join(["python", "bench/vae_layout.py", *sys.argv[1:]]),
        "machine": machine_info("cpu"),
        "weights": str(weights),
        "size": [w, h],
        "batch": args.batch,
        "dtype": str(dtype).removeprefix("torch."),
        "ms_per_image": {k: round(v, 3) for k, v in med.items()},
        "speedup": round(med["default"] / med["channels_last"], 3),
        "max_abs_latent_difference": float((out["default"] - out["channels_last"]).abs().max()),
        "latent_std": float(out["default"].std()),
    }


def main(argv: list[str] | None = None) -> int:
    from x2video.cli.args import size_arg

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--weights", type=Path, help="model folder or run (default: the shipped weights)")
    p.add_argument("--size", type=size_arg, default=(160, 112), help="WxH of the encoded images (default: the shipped model's 160x112)")
    p.add_argument("--batch", type=int, default=4, help="images per encoder call (a 5-frame window encodes 4 new frames)")
    p.add_argument("--repeats", type=int, default=25)
    p.add_argument("--threads", type=int, default=0, help="torch threads (0: torch's default)")
    p.add_argument("--bf16", action="store_true", help="both layouts in bfloat16 (the --bf16-encoder option)")
    p.add_argument("--out", type=Path, default=RESULTS)
    args = p.parse_args(argv)
    if args.repeats < 4 or args.batch < 1:
        p.error("--repeats must be >= 4 and --batch >= 1")
    result = measure(args)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    tmp = args.out.with_name(f".{args.out.name}.tmp")
    tmp.write_text(json.dumps(result, indent=2) + "\n")
    tmp.replace(args.out)
    print(json.dumps({k: result[k] for k in ("ms_per_image", "speedup", "max_abs_latent_difference")}, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
