"""Benchmark: Hybrid Self-Attention (paper Sec. Hybrid Self-Attention) vs plain self-attention vs full spatio-temporal attention.

The paper's claim: Multi-Head Full temporal attention keeps self-attention's cost (each
query still sees L keys; heads only read other frames), while full spatio-temporal
attention (every token of N frames attends all N*L tokens) grows with N. For N frames of
an h x w latent at C channels we time one attention layer (projections + attention +
output projection) in each variant, and the temporal branch alone against the
self-attention branch alone (projections + SDPA, no output projection).

Time: the fastest of --repeats interleaved calls. On CPU the clock is the process's CPU
time with one intra-op thread by default, because wall time on a machine shared with other
jobs measures them as much as us; on CUDA it is wall time around synchronised calls.

Memory: peak bytes allocated by PyTorch during one call. On CUDA:
`torch.cuda.max_memory_allocated` after `reset_peak_memory_stats`. On CPU: the PyTorch
profiler with `profile_memory=True` records every allocation and free of the CPU
allocator; the live-bytes peak is replayed from its memory timeline
(`torch.profiler._memory_profiler.MemoryProfile`, the data behind
`profile.export_memory_timeline`). Inputs and weights that exist before the call are not
counted.

    python -m bench.attention                          # C=320, 5 heads, 40x28, N = 5, 9, 17
    python -m bench.attention --channels 64 --heads 8  # the tiny preset's first attention level width
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Callable

import torch
import torch.nn.functional as F
from diffusers.models.attention_processor import Attention, AttnProcessor2_0

from x2video.fields import parse_size
from x2video.model.config import HybridConfig
from x2video.model.context import AttnContext
from x2video.model.hybrid_attention import HybridSelfAttnProcessor
from x2video.model.processor_io import heads_merge, heads_split


def full_spatiotemporal(attn: Attention, x: torch.Tensor, n: int) -> torch.Tensor:
    """Every token of a window attends all N*L tokens of the window: (B*N, L, C) -> (B*N, L, C)."""
    bn, length, c = x.shape
    seq = x.reshape(bn // n, n * length, c)  # (B, N*L, C)
    q, k, v = (heads_split(p(seq), attn.heads) for p in (attn.to_q, attn.to_k, attn.to_v))  # (B, H, N*L, d)
    out = attn.to_out[0](heads_merge(F.scaled_dot_product_attention(q, k, v)))  # (B, N*L, C)
    return out.reshape(bn, length, c)


def time_all(variants: dict[str, Callable[[], torch.Tensor]], repeats: int, device: torch.device, clock: Callable[[], float]) -> dict[str, float]:
    """Fastest of `repeats` timed calls per variant after one warm-up each. Rounds interleave
    the variants so that load from other processes on a shared machine hits them alike;
    the minimum is the figure least disturbed by that load."""
    best = {name: float("inf") for name in variants}
    for fn in variants.values():
        fn()
    for _ in range(repeats):
        for name, fn in variants.items():
            if device.type == "cuda":
                torch.cuda.synchronize()
            t0 = clock()
            fn()
            if device.type == "cuda":
                torch.cuda.synchronize()
            best[name] = min(best[name], clock() - t0)
    return best


def peak_bytes(fn: Callable[[], torch.Tensor], device: torch.device) -> int:
    """Peak bytes PyTorch allocated during one call (see the module docstring for how)."""
    if device.type == "cuda":
        torch.cuda.synchronize()
        base = torch.cuda.memory_allocated()
        torch.cuda.reset_peak_memory_stats()
        fn()
        torch.cuda.synchronize()
        return torch.cuda.max_memory_allocated() - base
    from torch.profiler import ProfilerActivity, profile
    from torch.profiler import _memory_profiler as mp

    with profile(activities=[ProfilerActivity.CPU], profile_memory=True, record_shapes=True, with_stack=True) as prof:
        fn()
    live = peak = 0
    for _, action, key, size in mp.MemoryProfile(prof.profiler.kineto_results).timeline:
        if key[0].device.type != "cpu":
            continue
        if action == mp.Action.CREATE:
            live += size
        elif action == mp.Action.DESTROY:
            live -= size
        peak = max(peak, live)
    return peak


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--channels", type=int, default=320, help="feature channels C (SD 2.1 first level: 320)")
    ap.add_argument("--heads", type=int, default=5, help="attention heads (SD 2.1 first level: 5)")
    ap.add_argument("--size", default="40x28", help="latent WxH (320x224 pixels at f=8: 40x28)")
    ap.add_argument("--frames", type=int, nargs="+", default=[5, 9, 17])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    ap.add_argument("--dtype", default="float32", choices=["float32", "float16", "bfloat16"])
    ap.add_argument("--threads", type=int, default=1, help="torch intra-op threads on CPU")
    ap.add_argument("--clock", choices=["cpu", "wall"], default=None,
                    help="cpu: process CPU time (default on CPU; other jobs on a shared machine barely move it); "
                         "wall: elapsed time (default on CUDA)")
    ap.add_argument("--json", type=Path, help="also write the results here")
    args = ap.parse_args(argv)

    device, dtype = torch.device(args.device), getattr(torch, args.dtype)
    if device.type == "cpu":
        torch.set_num_threads(args.threads)
    clock_name = args.clock or ("cpu" if device.type == "cpu" else "wall")
    clock = time.process_time if clock_name == "cpu" else time.perf_counter
    w, h = parse_size(args.size)
    length, c = w * h, args.channels
    torch.manual_seed(0)
    attn = Attention(query_dim=c, heads=args.heads, dim_head=c // args.heads).to(device, dtype).eval()
    hybrid = HybridSelfAttnProcessor(attn, HybridConfig(lora_rank=8)).to(device, dtype)
    with torch.no_grad():
        hybrid.alpha_r.fill_(0.2)
        hybrid.alpha_t.fill_(0.2)  # non-zero: every branch is computed
    plain = AttnProcessor2_0()
    info = {"device": str(device), "dtype": args.dtype, "threads": torch.get_num_threads(), "channels": c,
            "heads": args.heads, "latent": f"{w}x{h}", "tokens_per_frame": length, "torch": torch.__version__,
            "clock": clock_name}
    print(f"# {info}")
    header = f"{'N':>3} {'variant':<28} {'ms/call':>9} {'ms/frame':>9} {'peak MiB':>9} {'x self':>7}"
    print(header)
    rows = []
    with torch.no_grad():
        for n in args.frames:
            x = torch.randn(n, length, c, device=device, dtype=dtype)
            key = AttnContext(num_frames=n, latent_size=(h, w), ref_positions=(0,), mode="key")
            interp = AttnContext(num_frames=n, latent_size=(h, w), ref_positions=(0, n - 1), mode="interp", level=1)
            variants: dict[str, Callable[[], torch.Tensor]] = {
                "self-attention layer": lambda: plain(attn, x),
                "hybrid layer (key)": lambda: hybrid(attn, x, x2v=key),
                "hybrid layer (interp)": lambda: hybrid(attn, x, x2v=interp),
                "full spatio-temporal layer": lambda: full_spatiotemporal(attn, x, n),
                "branch: self (qkv+sdpa)": lambda: hybrid._attend(attn, attn.to_q(x), attn.to_k(x), attn.to_v(x), None),
                "branch: MHF temporal": lambda: hybrid.temporal(attn, x, key),
                "branch: reference (interp)": lambda: hybrid.reference(attn, x, interp),
            }
            secs = time_all(variants, args.repeats, device, clock)
            res = {name: (secs[name], peak_bytes(fn, device)) for name, fn in variants.items()}
            base_layer, base_branch = res["self-attention layer"][0], res["branch: self (qkv+sdpa)"][0]
            for name, (sec, mem) in res.items():
                ratio = sec / (base_branch if name.startswith("branch") else base_layer)
                print(f"{n:>3} {name:<28} {sec * 1e3:9.2f} {sec * 1e3 / n:9.2f} {mem / 2**20:9.1f} {ratio:7.2f}")
                rows.append({"frames": n, "variant": name, "seconds": sec, "peak_bytes": mem, "ratio_to_self": ratio})
            temporal_ratio = res["branch: MHF temporal"][0] / base_branch
            print(f"{n:>3} => MHF temporal branch / self-attention branch = {temporal_ratio:.2f}x (target <= 1.3x); "
                  f"full spatio-temporal / self-attention layer = {res['full spatio-temporal layer'][0] / base_layer:.2f}x")
    if args.json:
        args.json.write_text(json.dumps({"info": info, "rows": rows}, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
