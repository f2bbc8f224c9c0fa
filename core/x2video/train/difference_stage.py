"""`x2video train difference`: tier 1's net fine-tuned for its difference over a shot's own frames (issue 52).

Where a shot carries its path-traced rgb, an edit renders over it inside its reach (`x2video.base.difference`): tier 0's
rebuild from the passes carries what the passes split exactly (an albedo edit's diffuse term, a metallic edit's
diffuse and glossy colours), and misses how the edit changes the light itself: the glossy self-reflection of an
object made brighter, its interreflection, a sharper or blurrier highlight. The difference net adds that: its frame's
residual over the formula, (R(edited) - F(edited)) - (R(original) - F(original)), on top of tier 0's frame (R the
tier-1 net's frame, F albedo x irradiance under it). It is learnt from rooms path-traced before and after one
look-dev change (`x2video.train.difference_data`): starting from the shipped tier-1 net, on random crops that hold the
edit (mirrored, the light scaled), the loss is the L1 between display images (`small_nets.tonemap_t` in the shot's
units) of max(tier 0 + that residual difference, 0) and the after render inside the edit's reach, plus
`whole_weight` times the same over the whole crop (beyond the reach the frame should be the base). R is the frame as
the tier renders it: the formula kept where the channels hold no light (there the residual is 0).

Validation on held-out rooms, whole frames: PSNR of display images pooled over their frames, inside the reach and inside
the pixels the edit changed, of tier 0 plus the net's residual difference everywhere in the reach (``difference``: what
the stage renders with a difference net) and the stage's route without one (``stage``: base + R(edited) - R(original)
where roughness or normal changed, or metallic where the shot has no glossy colour pass, the rebuild elsewhere);
beside them, measured once before training, the same two with the shipped tier-1 net (the baseline's ``difference`` and
``stage``), the stage without tier 1 (``tier0``), the formula's difference (``formula``, tier 0 of `x2video.formula`) and
doing nothing (``nothing``); each per kind too. Checkpoints every `ckpt_every` steps, a run resumes from its last one;
the weights with the best ``difference`` PSNR inside the reach are kept in ``best/`` as difference.safetensors (fp16) and
difference.json: shipped beside residual.safetensors, `ResidualTier` takes them for its difference over the base.
"""
from __future__ import annotations

import json
import logging
import math
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Callable

import numpy as np
import torch

from x2video.io.atomic import atomic_path, write_json_atomic
from x2video.model import residual as R
from x2video.train.difference_data import KINDS, Pairs, cache_pairs, find_pairs, parse_kinds
from x2video.train.small_nets import optimiser_step, over_budget, tonemap_t, warm_cosine

log = logging.getLogger(__name__)

#: the scored frames of a validation pass: the net's, and the fixed ones each pair's cache holds
METHODS = ("difference", "stage", "tier0", "formula", "nothing")
REGIONS = ("reach", "inside")


@dataclass
class DifferenceTrainConfig:
    """What `x2video train difference` does; field docstrings are its help."""

    steps: int = 2000
    """Optimiser steps (a run stops earlier at --minutes)."""
    minutes: float = 0.0
    """Wall-clock limit in minutes (0: none); a checkpoint is written when it is reached."""
    batch: int = 8
    """Crops per step (each is run twice: original and edited)."""
    crop: int = 96
    """Side of the square random crops, each holding pixels its edit changed (a frame smaller than this: the frame)."""
    lr: float = 3e-4
    """AdamW peak learning rate (cosine decay to 5 % over `steps`, 100 warm-up steps); lower than tier 1's own, as a fine-tuning."""
    whole_weight: float = 0.1
    """Weight of the display L1 over the whole crop beside the one inside the edit's reach (beyond the reach the render is the base)."""
    exposure_aug: float = 2.0
    """Each crop's light is scaled by a random gain in [1/a, a] (light planes, base and after render alike; 1: off)."""
    kinds: str = "albedo,rough,gloss,metal_off,metal_on"
    """Comma-separated edit kinds to train and validate on (of albedo, rough, gloss, metal_off, metal_on, light; the
    stage takes a light edit over the base as a ratio of tier 0's rebuild, not as tier 1's difference)."""
    init: str = ""
    """Folder with the tier-1 net to start from (its residual.safetensors; empty: the shipped weights')."""
    val_every: int = 100
    """Validate on the held-out rooms (whole frames) every this many steps."""
    ckpt_every: int = 100
    """Write a resumable checkpoint every this many steps."""
    seed: int = 0
    """Seed of the crops."""


def init_net(init: str) -> tuple[R.ResidualNet, Path]:
    """The tier-1 net a run starts from (float32, train mode) and its folder: `init`, or the shipped weights'; its output
    layer zeroed, so that the run starts at tier 0's rebuild exactly (no residual) with tier 1's features. From the
    shipped output layer it started 3.2 dB below the rebuild on the validation pairs (25.98 against 29.21 in the reach)
    and spent its first hundred steps unlearning it."""
    from x2video.weights import shipped_weights, where_weights_are_looked_for

    folder = Path(init) if init else shipped_weights()
    if folder is None or not (folder / "residual.safetensors").is_file():
        where = folder if folder is not None else where_weights_are_looked_for()
        raise FileNotFoundError(f"{where}: no residual.safetensors to start the difference net from (--init FOLDER)")
    net = R.load(folder)
    if net.cfg.hints:
        raise ValueError(f"{folder}: the tier-1 net reads screen-space hints; its difference runs on whole frames only and "
                         "the edit pairs cache no hint planes: start from a net without them")
    with torch.no_grad():
        net.out.weight.zero_()
        net.out.bias.zero_()
    return net.train(), folder


def tier_frames(net, x: torch.Tensor, keep: torch.Tensor) -> torch.Tensor:
    """Tier 1's frames (N, 3, H, W) of features x (N, C_in, H, W): the net over the formula, the formula where `keep`
    (N, 1, H, W) says the channels hold no light (`tiers.residual.keep_formula_where_unseen`)."""
    shading = torch.expm1(x[:, R.FORMULA_PLANES])  # (N, 3, H, W)
    return keep * shading + (1 - keep) * R.apply(net, x, shading)


def residual_over_formula(net, x: torch.Tensor, keep: torch.Tensor) -> torch.Tensor:
    """R - F (N, 3, H, W): what the net's frame adds to the formula under it (0 where `keep` keeps the formula)."""
    return tier_frames(net, x, keep) - torch.expm1(x[:, R.FORMULA_PLANES])


def over_base(net, b: dict[str, torch.Tensor]) -> torch.Tensor:
    """max(tier 0 + (R - F)(edited) - (R - F)(original), 0) (N, 3, H, W) of a batch of crops (`Pairs.crops`), both frames
    in one pass; beyond the reach tier 0's frame is the base and the residuals' difference is the net's to keep at 0."""
    r = residual_over_formula(net, torch.cat([b["x_o"], b["x_e"]]), torch.cat([b["k_o"], b["k_e"]]))  # (2N, 3, H, W)
    r_o, r_e = r.chunk(2)
    return (b["tier0"] + r_e - r_o).clamp_min(0)


def loss_fn(out: torch.Tensor, b: dict[str, torch.Tensor], whole_weight: float) -> torch.Tensor:
    """L1 of display images (the shot's units) inside the reach, plus `whole_weight` times it over every pixel."""
    d = (tonemap_t(out / b["scale"]) - tonemap_t(b["target"] / b["scale"])).abs()  # (N, 3, H, W)
    inside = (d * b["reach"]).sum() / (3 * b["reach"].sum()).clamp_min(1)
    return inside + whole_weight * d.mean()


class _Pooled:
    """Squared errors and counts per key, pooled; `psnr` per key (None where nothing was counted)."""

    def __init__(self) -> None:
        self.sse: dict[tuple, float] = {}
        self.n: dict[tuple, int] = {}

    def add(self, key: tuple, err: torch.Tensor, mask: torch.Tensor) -> None:
        self.sse[key] = self.sse.get(key, 0.0) + float((err * mask).sum())
        self.n[key] = self.n.get(key, 0) + 3 * int(mask.sum())

    def psnr(self, key: tuple) -> float | None:
        n = self.n.get(key, 0)
        return None if n == 0 else 10 * math.log10(1.0 / max(self.sse[key] / n, 1e-12))


@torch.no_grad()
def score(net, pairs: Pairs) -> dict:
    """PSNRs of a validation pass (see the module docstring): {method: {region: dB}}, ``by_kind``: {kind: {method: {region:
    dB}}}, ``frames``."""
    was = net.training
    net.eval()
    pooled = _Pooled()
    originals: dict[tuple[int, int], torch.Tensor] = {}
    t32 = lambda a: torch.from_numpy(np.asarray(a, np.float32))[None]  # noqa: E731  (1, C, H, W)
    for bf, pf, t, kind, scale in pairs.frames:
        key = (id(bf), t)
        if key not in originals:
            originals[key] = tier_frames(net, t32(bf["x"][t]), t32(bf["keep"][t])[:, None])
        r_e = tier_frames(net, t32(pf["x"][t]), t32(pf["keep"][t])[:, None])
        base, reach, glossy = t32(bf["base"][t]), t32(pf["reach"][t])[:, None], t32(pf["glossy"][t])[:, None]
        tier0 = t32(pf["tier0"][t])
        f_o, f_e = (torch.expm1(t32(a["x"][t])[:, R.FORMULA_PLANES]) for a in (bf, pf))
        learned = (tier0 + (r_e - f_e) - (originals[key] - f_o)).clamp_min(0)
        diff = (base + r_e - originals[key]).clamp_min(0)
        frames = {"difference": torch.where(reach > 0, learned, base), "stage": torch.where(glossy > 0, diff, tier0),
                  "tier0": tier0, "formula": t32(pf["formula"][t]), "nothing": base}
        truth = tonemap_t(t32(pf["target"][t]) / scale)
        masks = {"reach": reach, "inside": t32(pf["inside"][t])[:, None]}
        for m, f in frames.items():
            err = (tonemap_t(f / scale) - truth) ** 2
            for r, mask in masks.items():
                pooled.add((m, r), err, mask)
                pooled.add((kind, m, r), err, mask)
    net.train(was)
    kinds = [k for k in KINDS if any(fr[3] == k for fr in pairs.frames)]
    return {**{m: {r: pooled.psnr((m, r)) for r in REGIONS} for m in METHODS},
            "by_kind": {k: {m: {r: pooled.psnr((k, m, r)) for r in REGIONS} for m in METHODS} for k in kinds},
            "frames": len(pairs.frames)}


def _dataset(pairs: list, val: list, data: Path, size: tuple[int, int] | None) -> dict:
    """What difference.json says the net was trained on (rooms and pairs per kind; `size` (H, W) said as [W, H])."""
    rooms = lambda ps: sorted({p.room for p in ps})  # noqa: E731
    count = lambda ps: {k: sum(p.kind == k for p in ps) for k in KINDS if any(p.kind == k for p in ps)}  # noqa: E731
    return {"data": data.name, "size": None if size is None else [size[1], size[0]], "train_rooms": rooms(pairs), "train_pairs": count(pairs),
            "val_rooms": rooms(val), "val_pairs": count(val)}


def train(data: Path, out: Path, cfg: DifferenceTrainConfig, *, threads: int = 2, progress: Callable[[dict], None] | None = None) -> dict:
    """Fine-tune (or resume) the difference net on the pairs of `data/train`, validated on `data/val` (else `data/test`);
    returns the summary."""
    torch.set_num_threads(max(1, threads))
    kinds = parse_kinds(cfg.kinds)
    cache = out / "cache"
    train_pairs = find_pairs(data, "train", kinds)
    val_split = "val" if find_pairs(data, "val", kinds) else "test"
    val_pairs = find_pairs(data, val_split, kinds)
    if not train_pairs:
        raise ValueError(f"{data}: no finished edit pairs of {', '.join(kinds)} in train/room_*/ (make them with `python -m bench.edits_data`)")
    note = lambda room: log.info("caching the edit pairs of %s", room)  # noqa: E731
    tr = Pairs(cache_pairs(train_pairs, cache, note), [p.kind for p in train_pairs])
    va = Pairs(cache_pairs(val_pairs, cache, note), [p.kind for p in val_pairs], scoring=True) if val_pairs else None
    if not len(tr):
        raise ValueError(f"{data}: no frame of the train pairs that an edit reaches")
    size = tr.frames[0][1]["reach"].shape[1:]
    net, init_folder = init_net(cfg.init)
    from x2video.model.residual_engine import weights_sha

    init = {"folder": init_folder.name, "residual_sha": weights_sha(net)}
    opt = torch.optim.AdamW(net.parameters(), lr=cfg.lr, weight_decay=1e-4)
    step, best, baseline = 0, -1.0, None
    ck = out / "checkpoint.pt"
    if ck.is_file():
        state = torch.load(ck, map_location="cpu", weights_only=False)
        net.load_state_dict(state["net"])
        opt.load_state_dict(state["opt"])
        step, best, baseline, init = int(state["step"]), float(state["best"]), state["baseline"], state["init"]
        log.info("resuming %s at step %d", out, step)
    elif va is not None:
        baseline = score(net, va)  # the shipped tier-1 net's difference, before any step
    rng = np.random.default_rng([cfg.seed, step])
    history: list[dict] = []
    t0 = time.perf_counter()
    trained_on = _dataset(train_pairs, val_pairs, data, size)
    summary = {"config": asdict(cfg), "train_frames": len(tr), "val_frames": len(va) if va else 0, "val_split": val_split,
               "trained_on": trained_on, "init": init, "baseline": baseline}

    def checkpoint() -> None:
        out.mkdir(parents=True, exist_ok=True)
        with atomic_path(ck) as tmp:
            torch.save({"net": net.state_dict(), "opt": opt.state_dict(), "step": step, "best": best, "baseline": baseline,
                        "init": init}, tmp)

    net.train()
    while step < cfg.steps:
        for g in opt.param_groups:
            g["lr"] = cfg.lr * warm_cosine(step, cfg.steps)
        b = {k: torch.from_numpy(v) for k, v in tr.crops(rng, cfg.batch, cfg.crop, cfg.exposure_aug).items()}
        loss = loss_fn(over_base(net, b), b, cfg.whole_weight)
        optimiser_step(net, opt, loss)
        step += 1
        over = over_budget(t0, cfg.minutes)
        if va is not None and (step % cfg.val_every == 0 or step == cfg.steps or over):
            v = score(net, va)
            v.update(step=step, loss=float(loss.detach()), seconds=round(time.perf_counter() - t0, 1))
            history.append(v)
            if progress is not None:
                progress({**v, "baseline": baseline})
            if v["difference"]["reach"] is not None and v["difference"]["reach"] > best:
                best = v["difference"]["reach"]
                R.save(net, out / "best", {"step": step, "val": v, "baseline": baseline, "trained_on": trained_on, "init": init,
                                           "train_config": asdict(cfg)}, name="difference")
        if step % cfg.ckpt_every == 0 or over:
            checkpoint()
        if over:
            break
    checkpoint()
    R.save(net, out / "last", {"step": step, "trained_on": trained_on, "init": init}, name="difference")
    summary.update(steps=step, seconds=round(time.perf_counter() - t0, 1), best_val_psnr=best if va is not None else None, history=history)
    prev = json.loads((out / "results.json").read_text()) if (out / "results.json").is_file() else {}
    write_json_atomic(out / "results.json", {**prev, "difference": summary})
    return summary
