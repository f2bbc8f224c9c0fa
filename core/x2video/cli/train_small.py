"""`x2video train residual|difference|fill`: the small nets' training stages (the tier-1 net, its difference over a
shot's frames, the learned keyframe fill), each resumable; registered under `x2video train` by `x2video.cli.train`."""
from __future__ import annotations

import argparse
from pathlib import Path

from x2video.fields import add_fields, from_args


def _small_net_args(p: argparse.ArgumentParser, config: type, shots: str, cache: str) -> None:
    """The flags of a small net's training (the tier-1 residual net, the keyframe fill): data, run folder, threads and
    the stage's `config` fields; `shots` says what the data set's shot folders hold, `cache` adds to --out's help."""
    p.add_argument("--data", required=True, help=f"data set with train/ and val/ (or test/) {shots}")
    p.add_argument("--out", required=True, help=f"run folder (resumes from its checkpoint.pt{cache})")
    p.add_argument("--threads", type=int, default=2, help="torch CPU threads")
    add_fields(p, config)


def cmd_residual(args: argparse.Namespace) -> int:
    from x2video.train.residual_stage import ResidualTrainConfig, train

    cfg = from_args(ResidualTrainConfig, args)
    out = Path(args.out)

    def show(v: dict) -> None:
        print(f"step {v['step']:6d}  loss {v['loss']:.4f}  val PSNR {v['psnr']:.2f} dB (formula {v['psnr_formula']:.2f},"
              f" formula where unseen {v['psnr_kept']:.2f})  {v['seconds']:.0f} s", flush=True)

    summary = train(Path(args.data), out, cfg, threads=args.threads, progress=show)
    print(f"{summary['steps']} steps in {summary['seconds']:.0f} s on {summary['train_frames']} frames; best val PSNR {summary['best_val_psnr']:.2f} dB;"
          f" weights in {out / 'best'} (ship: copy residual.safetensors and residual.json beside the model's weights)")
    return 0


def cmd_difference(args: argparse.Namespace) -> int:
    from x2video.train.difference_stage import DifferenceTrainConfig, train

    cfg = from_args(DifferenceTrainConfig, args)
    out = Path(args.out)

    def db(v: float | None) -> str:
        return "-" if v is None else f"{v:.2f}"

    def show(v: dict) -> None:
        base = v["baseline"] or {}
        was = lambda m: db(base.get(m, {}).get("reach"))  # noqa: E731
        print(f"step {v['step']:6d}  loss {v['loss']:.4f}  val PSNR in the reach {db(v['difference']['reach'])} dB (inside "
              f"{db(v['difference']['inside'])}; shipped tier 1 {was('difference')}, formula {was('formula')}, tier 0 {was('tier0')}, "
              f"nothing {was('nothing')}); as the stage routes it {db(v['stage']['reach'])} (shipped {was('stage')})  {v['seconds']:.0f} s",
              flush=True)

    summary = train(Path(args.data), out, cfg, threads=args.threads, progress=show)
    best = summary["best_val_psnr"]
    print(f"{summary['steps']} steps in {summary['seconds']:.0f} s on {summary['train_frames']} frames"
          + (f"; best val PSNR in the reach {best:.2f} dB" if best is not None else "; no held-out pairs")
          + f"; weights in {out / 'best'} (ship: copy difference.safetensors and difference.json beside residual.safetensors)")
    return 0


def cmd_fill(args: argparse.Namespace) -> int:
    from x2video.train.fill_stage import FillTrainConfig, train_folder

    cfg = from_args(FillTrainConfig, args)
    out = Path(args.out)

    def show(v: dict) -> None:
        scores = f"val PSNR {v['psnr']:.2f} dB (classical fill {v['psnr_classical']:.2f})" if "psnr" in v else "no held-out shots"
        print(f"step {v['step']:6d}  loss {v['loss']:.4f}  {scores}  {v['seconds']:.0f} s", flush=True)

    summary = train_folder(Path(args.data), out, cfg, threads=args.threads, progress=show)
    best = summary["best_val_psnr"]
    print(f"{summary['steps']} steps in {summary['seconds']:.0f} s on {summary['train_shots']} shots"
          + (f"; best val PSNR {best:.2f} dB" if best is not None else "")
          + f"; weights in {out / 'best'} (ship: copy fill.safetensors and fill.json beside the model's weights)")
    return 0


def register_small(sub) -> None:
    """Add the small nets' stages to `x2video train`'s subparsers."""
    s = sub.add_parser("residual", help="the tier-1 network: one pass over albedo x irradiance, fitted to path-traced shots")
    from x2video.train.residual_stage import ResidualTrainConfig

    _small_net_args(s, ResidualTrainConfig, "shot folders holding the five channels and rgb", "")
    s.set_defaults(func=cmd_residual)

    s = sub.add_parser("difference", help="tier 1's net fine-tuned for its difference over a shot's frames, on rooms path-traced before and after an edit",
                       description="Starts from the shipped tier-1 net (--init) and fits tier 0's rebuild plus its residual difference "
                                   "over the formula to Cycles' render after the edit, inside the edit's reach. "
                                   "Data: `python -m bench.edits_data --out DATA/{train,val}`. Resumable: run the same command again to continue.")
    from x2video.train.difference_stage import DifferenceTrainConfig

    _small_net_args(s, DifferenceTrainConfig, "rooms (room_<seed>/before and after_<kind>/ with edits.json, as bench.edits_data makes them)",
                    "; the pairs are cached in OUT/cache")
    s.set_defaults(func=cmd_difference)

    s = sub.add_parser("fill", help="the learned keyframe fill: a small net correcting the classical fill between path-traced keyframes",
                       description="Trains on shots with rgb on every frame (random keyframe spacing and phase, a frame "
                                   "between held out). Resumable: run the same command again to continue.")
    from x2video.train.fill_stage import FillTrainConfig

    _small_net_args(s, FillTrainConfig, "shot folders: rgb on every frame, G-buffers, depth and cameras.json where they have them",
                    "; the shots are cached in OUT/cache")
    s.set_defaults(func=cmd_fill)
