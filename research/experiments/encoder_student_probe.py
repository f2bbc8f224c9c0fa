"""Feasibility probe (not a training stage, ships nothing): can a small CNN stand in for the VAE encoder on the
intrinsic channels, to cut the per-frame fixed cost that bounds LCM-2's speed-up (model card, table d)?

Encodes channel images of training rooms with the shipped VAE's encoder (posterior mode, the latents the UNet
was trained on), fits a plain strided CNN to them for a fixed wall-clock budget, and reports its relative
latent error on held-out rooms and its speed against the encoder's, side by side at the given thread count.

    python research/experiments/encoder_student_probe.py --data DATA [--rooms 12] [--minutes 10] [--threads 2]
        [--out student.pt] [--json result.json]
    python research/experiments/encoder_student_probe.py eval student.pt [--width 64 --depth 3] -- EVAL_ARGS...

The second form runs `x2video eval EVAL_ARGS` with every VAE encoding done by the saved student (the
results' model lines do not show it). Results of the run reported in the model card's preface, table (d):
research/experiments/results/.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch
import torch.nn as nn

KINDS = ("albedo", "normal", "roughness", "metallic", "shading")


class Student(nn.Module):
    """3 x H x W in [-1, 1] -> 4 x H/4 x W/4 latents: two strided convs, `depth` 3x3 convs at latent size."""

    def __init__(self, width: int = 64, depth: int = 3) -> None:
        super().__init__()
        layers: list[nn.Module] = [nn.Conv2d(3, width // 2, 3, 2, 1), nn.SiLU(), nn.Conv2d(width // 2, width, 3, 2, 1), nn.SiLU()]
        for _ in range(depth):
            layers += [nn.Conv2d(width, width, 3, 1, 1), nn.SiLU()]
        layers.append(nn.Conv2d(width, 4, 3, 1, 1))
        self.net = nn.Sequential(*layers)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.net(x)


def images(data: Path, split: str, rooms: int, frames: int, size: tuple[int, int]) -> np.ndarray:
    """(n, 3, H, W) float16 VAE-range images of every kind, from the first `rooms` rooms of `split`."""
    from x2video.eval.data import load_eval_shots
    from x2video.model.shading import classical_shading
    from x2video.model.vae import to_vae_range
    from x2video.conditioning.frame import plain_conditioning

    out = []
    for s in load_eval_shots(data, split, rooms, frames, size):
        for t in range(s.num_frames):
            c = plain_conditioning(s.shot, t)
            for k in KINDS:
                x = classical_shading(c.channels, c.amr_mask) if k == "shading" else c.channels[k]
                out.append(to_vae_range(k, x).transpose(2, 0, 1).astype(np.float16))
    return np.stack(out)


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["eval"]:
        e = argparse.ArgumentParser(prog="encoder_student_probe.py eval", epilog="then -- and the arguments of x2video eval")
        e.add_argument("student", type=Path)
        e.add_argument("--width", type=int, default=64)
        e.add_argument("--depth", type=int, default=3)
        own, rest = (argv[1:argv.index("--")], argv[argv.index("--") + 1:]) if "--" in argv else (argv[1:], [])
        ea = e.parse_args(own)
        return evaluate_with_student(ea.student, ea.width, ea.depth, rest)
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--data", type=Path, required=True)
    p.add_argument("--weights", type=Path, default=Path(__file__).resolve().parents[2] / "resources" / "x2video-tiny")
    p.add_argument("--rooms", type=int, default=12, help="training rooms (default 12)")
    p.add_argument("--frames", type=int, default=65)
    p.add_argument("--minutes", type=float, default=10.0, help="training budget (default 10)")
    p.add_argument("--width", type=int, default=64)
    p.add_argument("--depth", type=int, default=3)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--out", type=Path, help="save the student's state dict here")
    p.add_argument("--json", type=Path, help="write the figures here")
    a = p.parse_args(argv)
    torch.set_num_threads(a.threads)
    torch.manual_seed(0)
    from x2video.model.pipeline import X2VideoModel

    model = X2VideoModel.from_pretrained(a.weights)
    size = (160, 112)
    t0 = time.perf_counter()
    train_x = images(a.data, "train", a.rooms, a.frames, size)
    test_x = images(a.data, "test", 4, 17, size)

    @torch.no_grad()
    def teacher(x: np.ndarray) -> torch.Tensor:
        return torch.cat([model.vae.encode(torch.from_numpy(x[i:i + 64]).float()).latent_dist.mode() for i in range(0, len(x), 64)])

    train_z, test_z = teacher(train_x), teacher(test_x)
    prep = time.perf_counter() - t0
    print(f"{len(train_x)} training and {len(test_x)} held-out images encoded in {prep:.0f} s", file=sys.stderr)
    student = Student(a.width, a.depth)
    opt = torch.optim.AdamW(student.parameters(), lr=2e-3, weight_decay=0.0)
    steps, t1 = 0, time.perf_counter()
    budget = a.minutes * 60
    rng = np.random.default_rng(0)
    while time.perf_counter() - t1 < budget:
        idx = rng.integers(0, len(train_x), 32)
        frac = (time.perf_counter() - t1) / budget
        for g in opt.param_groups:
            g["lr"] = 2e-3 * 0.5 * (1 + np.cos(np.pi * min(frac, 1.0)))
        loss = nn.functional.mse_loss(student(torch.from_numpy(train_x[idx]).float()), train_z[idx])
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        steps += 1
        if steps % 200 == 0:
            print(f"step {steps}: mse {loss.item():.5f}", file=sys.stderr)
    with torch.no_grad():
        pred = torch.cat([student(torch.from_numpy(test_x[i:i + 64]).float()) for i in range(0, len(test_x), 64)])
        per_kind = {}
        for j, k in enumerate(KINDS):
            sel = slice(j, None, len(KINDS))
            per_kind[k] = float((pred[sel] - test_z[sel]).norm() / test_z[sel].norm())
        rel = float((pred - test_z).norm() / test_z.norm())
        x5 = torch.from_numpy(test_x[:25]).float()
        timing = {}
        for name, fn in (("vae_encoder", lambda: model.vae.encode(x5).latent_dist.mode()), ("student", lambda: student(x5))):
            fn()
            s = time.perf_counter()
            for _ in range(5):
                fn()
            timing[name] = (time.perf_counter() - s) / 5 / 25
    result = {"rooms": a.rooms, "images": len(train_x), "steps": steps, "minutes": a.minutes, "width": a.width, "depth": a.depth,
              "params": sum(p.numel() for p in student.parameters()), "threads": a.threads,
              "held_out_relative_error": rel, "held_out_relative_error_per_kind": per_kind,
              "seconds_per_image": timing, "encoder_over_student": timing["vae_encoder"] / timing["student"]}
    print(json.dumps(result, indent=1))
    if a.out:
        torch.save(student.state_dict(), a.out)
    if a.json:
        a.json.write_text(json.dumps(result, indent=1))
    return 0


def evaluate_with_student(student_path: Path, width: int, depth: int, eval_args: list[str]) -> int:
    """`x2video eval EVAL_ARGS` with every VAE encoding (channels, shading prior, reference image) done by the
    student instead of the VAE's encoder; decoding is unchanged. For the probe only."""
    from x2video.cli import main as cli_main
    from x2video.model import pipeline
    from x2video.model.vae import images_to_tensor

    student = Student(width, depth)
    student.load_state_dict(torch.load(student_path))
    student.eval().requires_grad_(False)

    def _encode(self, imgs):  # same contract as X2VideoModel._encode
        with torch.no_grad():
            return student(images_to_tensor(imgs, self.device, torch.float32)).to(self.dtype)

    pipeline.X2VideoModel._encode = _encode
    return cli_main(["eval", *eval_args])


if __name__ == "__main__":
    sys.exit(main())
