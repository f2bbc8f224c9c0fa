"""Edit pairs for `x2video train difference` (issue 52): rooms path-traced before and after one look-dev change, read
once into float16 arrays of what tier 1's difference over the base reads and what it must give.

Layout (`bench.edits_data`): ``<split>/room_<seed>/before/``, a Blender multi-layer EXR shot with rgb, and
``after_<kind>/``, the same room re-rendered after one change, whose ``edits.json`` holds the change in x2video's terms
(``edits``: an `x2video.Edits` dict). A pair is complete when ``before/shot.json`` and ``after_<kind>/edits.json`` exist
(both are written last), so a data set still being rendered trains on what is finished.

Per frame of a pair, what `x2video.base.stage.edited_frame` sees and gives: the original conditioning
(`plain_conditioning`) and the edited one (`apply_edits`, a metal made non-metal relit as the stage relights it,
`difference.relit_metal`), each as the tier-1 net's features (`residual.features`) with the weight by which tier 1 keeps
the formula where the channels hold no light (`tiers.residual.keep_formula_where_unseen`); the base (the before render)
and the target (the after render), both in the model's exposure (times the before shot's irradiance_scale, as the
stage's base); the edit's reach (`difference.reach`) and the pixels it changed. For scoring, the stage's frame without
tier 1 (``tier0``: the rebuild from passes), where the stage takes tier 1's difference instead (``glossy``), and the
formula's difference (``formula``: albedo x irradiance, `x2video.formula`).
"""
from __future__ import annotations

import json
import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from x2video.io.atomic import atomic_path
from x2video.train.residual_stage import NOISY_PLANES as LIGHT_PLANES  # log irradiance and log formula: what a gain changes

log = logging.getLogger(__name__)

#: the look-dev changes `bench.edits_data` renders
KINDS = ("albedo", "rough", "gloss", "metal_off", "metal_on", "light")
#: arrays of a pair's cache file, per frame; (C, H, W) float16 planes or (H, W) masks
PAIR_ARRAYS = ("x", "keep", "target", "reach", "inside", "tier0", "glossy", "formula")
#: arrays of a room's before cache file, per frame
BEFORE_ARRAYS = ("x", "keep", "base")
#: a change to this code that changes what a cache file holds makes older ones be made again
CACHE_VERSION = 1


@dataclass(frozen=True)
class PairDir:
    """One complete pair on disk: the room's before shot and one after render with its edits.json."""

    split: str
    room: str  # room_<seed>
    kind: str
    before: Path
    after: Path

    @property
    def key(self) -> str:
        return f"{self.split}_{self.room}_{self.kind}"


def find_pairs(data: Path, split: str, kinds: tuple[str, ...]) -> list[PairDir]:
    """The complete pairs of `kinds` under `data/split/room_*/` in a fixed order."""
    out = []
    for room in sorted((data / split).glob("room_*")):
        before = room / "before"
        if not (before / "shot.json").is_file():
            continue
        for kind in kinds:
            after = room / f"after_{kind}"
            if (after / "edits.json").is_file() and (after / "shot.json").is_file():
                out.append(PairDir(split, room.name, kind, before, after))
    return out


def parse_kinds(text: str) -> tuple[str, ...]:
    kinds = tuple(k.strip() for k in text.split(",") if k.strip())
    bad = [k for k in kinds if k not in KINDS]
    if bad or not kinds:
        raise ValueError(f"kinds: {', '.join(bad) or 'none given'}; each one of {', '.join(KINDS)}")
    return kinds


def _save(path: Path, arrays: dict[str, np.ndarray]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:
            np.savez(fh, version=np.int32(CACHE_VERSION), **arrays)


def _fresh(path: Path) -> bool:
    if not path.is_file():
        return False
    with np.load(path) as d:
        return "version" in d.files and int(d["version"]) == CACHE_VERSION


def cache_pairs(pairs: list[PairDir], cache: Path, log_room=None) -> list[tuple[Path, Path]]:
    """Read each pair once into `cache` (float16): per pair (the room's before file, shared by its pairs; the pair's own
    file). A room's before shot is read once for all its pairs; `log_room(room)` is called for each room read."""
    out: dict[PairDir, tuple[Path, Path]] = {}
    rooms: dict[tuple[str, str], list[PairDir]] = {}
    for pair in pairs:
        rooms.setdefault((pair.split, pair.room), []).append(pair)
    for (split, room), todo in rooms.items():
        before_file = cache / f"{split}_{room}_before.npz"
        files = {pair: (before_file, cache / f"{pair.key}.npz") for pair in todo}
        stale = [pair for pair in todo if not _fresh(files[pair][1])]
        if stale or not _fresh(before_file):
            if log_room is not None:
                log_room(f"{split}/{room}")
            _cache_room(todo[0].before, stale, before_file, {pair: files[pair][1] for pair in stale})
        out.update(files)
    return [out[pair] for pair in pairs]


def _cache_room(before_dir: Path, pairs: list[PairDir], before_file: Path, pair_files: dict[PairDir, Path]) -> None:
    from x2video.base.difference import over_base, reach, relit_metal
    from x2video.base.stage import edited_frame
    from x2video.conditioning.edited import apply_edits
    from x2video.conditioning.frame import plain_conditioning
    from x2video.edits.model import Edits
    from x2video.formula import formula
    from x2video.io.load import load_shot
    from x2video.model import residual as R

    shot = load_shot(before_dir)
    missing = [c for c in ("albedo", "normal", "roughness", "metallic", "irradiance", "rgb") if not shot.has(c)]
    if missing:
        raise ValueError(f"{before_dir}: lacks {', '.join(missing)}; an edit pair needs the five channels and rgb")
    s = float(shot.info.irradiance_scale)
    originals = [plain_conditioning(shot, t) for t in range(shot.num_frames)]
    bases = [np.asarray(shot.channel("rgb", t), np.float64) * s for t in range(shot.num_frames)]  # the stage's base: model exposure
    if not _fresh(before_file):
        x = [R.features(o.channels)[0].astype(np.float16) for o in originals]
        _save(before_file, {"x": np.stack(x), "keep": np.stack([_keep(o.channels) for o in originals]),
                            "base": np.stack([b.transpose(2, 0, 1).astype(np.float16) for b in bases]), "scale": np.float32(s)})
    for pair in pairs:
        after = load_shot(pair.after)
        if after.num_frames != shot.num_frames or after.size != shot.size:
            raise ValueError(f"{pair.after}: {after.num_frames} frames of {after.size}, the before render has {shot.num_frames} of {shot.size}")
        doc = json.loads((pair.after / "edits.json").read_text())
        edits = Edits.from_dict(doc.get("edits"), where=f"{pair.after / 'edits.json'}: edits")
        arrays: dict[str, list] = {k: [] for k in PAIR_ARRAYS}
        for t, (original, base) in enumerate(zip(originals, bases)):
            edited = apply_edits(shot, edits, t)
            relit = relit_metal(original, edited)  # what the stage hands tier 1 (`edited_frame`)
            wanted: list[np.ndarray] = []

            def spy(e, o, where, wanted=wanted):  # the stage's call of tier 1: `where` is where it takes its difference
                wanted.append(where)
                return np.zeros((*where.shape, 3), np.float32), np.zeros((*where.shape, 3), np.float32)

            edited_frame(base, original, edited, glossy_tier=True, residual=spy)
            tier0 = edited_frame(base, original, edited, glossy_tier=False, residual=None)[0]
            near = reach(original, edited)
            arrays["x"].append(R.features(relit.channels)[0].astype(np.float16))
            arrays["keep"].append(_keep(relit.channels))
            arrays["target"].append((np.asarray(after.channel("rgb", t), np.float64) * s).transpose(2, 0, 1).astype(np.float16))
            arrays["reach"].append(near)
            arrays["inside"].append(_changed(original, edited))
            arrays["tier0"].append(np.asarray(tier0).transpose(2, 0, 1).astype(np.float16))
            arrays["glossy"].append(wanted[0] if wanted else np.zeros(near.shape, bool))
            f = over_base(base, formula(relit.channels), formula(original.channels), near)
            arrays["formula"].append(f.transpose(2, 0, 1).astype(np.float16))
        _save(pair_files[pair], {k: np.stack(v) for k, v in arrays.items()} | {"scale": np.float32(s)})


def _changed(original, edited) -> np.ndarray:
    from x2video.base.difference import changed

    return changed(original, edited)


def _keep(channels) -> np.ndarray:
    """(H, W) float16: the weight of the formula over tier 1's frame where the channels hold no light (1 there, feathered
    2 px: `keep_formula_where_unseen`'s)."""
    from x2video.model.residual import unseen_light
    from x2video.tiers.regions import feathered

    h, w = next(np.shape(v)[:2] for v in channels.values() if v is not None)
    m = unseen_light(channels, (h, w))
    return (np.zeros((h, w)) if m is None or not m.any() else feathered(m, 2.0)).astype(np.float16)


class Pairs:
    """The cached frames of some pairs in memory: the before frames once per room, the rest per pair; frames an edit does
    not reach (its object out of view) are left out. `scoring` keeps the stage's frames for validation."""

    def __init__(self, files: list[tuple[Path, Path]], kinds: list[str], scoring: bool = False):
        self.before: dict[Path, dict[str, np.ndarray]] = {}
        #: (the room's before arrays, the pair's arrays, frame index, kind, the before shot's irradiance_scale)
        self.frames: list[tuple[dict[str, np.ndarray], dict[str, np.ndarray], int, str, float]] = []
        keys = PAIR_ARRAYS if scoring else ("x", "keep", "target", "reach", "inside", "tier0")
        for (bf, pf), kind in zip(files, kinds):
            if bf not in self.before:
                with np.load(bf) as d:
                    self.before[bf] = {k: d[k] for k in BEFORE_ARRAYS}
            with np.load(pf) as d:
                arrays, scale = {k: d[k] for k in keys}, float(d["scale"])
            for t in range(arrays["x"].shape[0]):
                if arrays["reach"][t].any():
                    self.frames.append((self.before[bf], arrays, t, kind, scale))

    def __len__(self) -> int:
        return len(self.frames)

    def crops(self, rng: np.random.Generator, n: int, size: int, exposure_aug: float = 1.0) -> dict[str, np.ndarray]:
        """`n` random crops (float32, a batch dimension first), each containing pixels its edit changed: features and
        keep weights of the original (``x_o``, ``k_o``) and edited frame (``x_e``, ``k_e``), ``base``, ``target``, the
        edit's ``reach`` (float 0/1) and the frame's ``scale``; half of them mirrored left-right (the normal's x too),
        each frame's light scaled by a random gain in [1/a, a] (light planes, base and target alike)."""
        keys = ("x_o", "k_o", "base", "x_e", "k_e", "target", "reach", "tier0", "scale")
        out: dict[str, list] = {k: [] for k in keys}
        for _ in range(n):
            i = int(rng.integers(len(self.frames)))
            bf, pf, t, _, scale = self.frames[i]
            h, w = pf["reach"].shape[1:]
            s = min(size, h, w)
            ys, xs = np.nonzero(pf["inside"][t] if pf["inside"][t].any() else pf["reach"][t])
            j = int(rng.integers(len(ys)))  # a changed pixel the crop holds
            r = int(rng.integers(max(0, ys[j] - s + 1), min(ys[j], h - s) + 1))
            c = int(rng.integers(max(0, xs[j] - s + 1), min(xs[j], w - s) + 1))
            win = (slice(r, r + s), slice(c, c + s))
            crop = {"x_o": bf["x"][t][:, win[0], win[1]], "k_o": bf["keep"][t][None, win[0], win[1]],
                    "base": bf["base"][t][:, win[0], win[1]], "x_e": pf["x"][t][:, win[0], win[1]],
                    "k_e": pf["keep"][t][None, win[0], win[1]], "target": pf["target"][t][:, win[0], win[1]],
                    "reach": pf["reach"][t][None, win[0], win[1]], "tier0": pf["tier0"][t][:, win[0], win[1]]}
            crop = {k: v.astype(np.float32) for k, v in crop.items()}
            if exposure_aug > 1:  # the same room under a brighter or dimmer light
                g = float(np.exp(rng.uniform(-1, 1) * np.log(exposure_aug)))
                for k in ("x_o", "x_e"):
                    crop[k][LIGHT_PLANES] = np.log1p(g * np.expm1(crop[k][LIGHT_PLANES]))
                crop["base"] *= g
                crop["target"] *= g
                crop["tier0"] *= g
            if rng.random() < 0.5:  # mirror left-right: the camera-space normal's x changes sign
                crop = {k: np.ascontiguousarray(v[:, :, ::-1]) for k, v in crop.items()}
                crop["x_o"][3] *= -1
                crop["x_e"][3] *= -1
            crop["scale"] = np.full((1, 1, 1), scale, np.float32)
            for k in keys:
                out[k].append(crop[k])
        return {k: np.stack(v) for k, v in out.items()}
