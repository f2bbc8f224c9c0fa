"""A shot's ground truth for scoring: its own rgb, or a truth rendered apart from the passes (``SHOT/truth/``).

A path-traced shot's Combined comes out of the same render as the irradiance pass the tiers read, so a tier that
passes irradiance through copies the truth's noise and scores for it. `x2video dataset truth` renders the same
camera and lights again, at more samples and with another noise seed, into ``SHOT/truth/000000.exr ...``
(linear float RGB, the Combined's units) and records how in ``SHOT/truth/truth.json``. Benches and
`x2video eval` score against `ground_truth(shot)`: that truth when it is complete, else the shot's rgb, and say
which (`Truth.label`). Only the scoring reads it: the renderer never sees it (its rgb is an input: keyframes, edits).
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable

import numpy as np

#: the folder beside a shot's frames, its frames' names and its record
TRUTH_DIR = "truth"
RECORD = "truth.json"
FORMAT = "x2video-truth"
#: what a result says when the shot's own rgb (the passes' Combined) was the truth
OWN = "the passes' own Combined"


def truth_frame_path(shot_dir: str | Path, t: int) -> Path:
    return Path(shot_dir) / TRUTH_DIR / f"{t:06d}.exr"


def shot_folder(shot: Any) -> Path | None:
    """The folder a loaded shot was read from (`ShotInfo.source`), or None (a shot in memory, a single file)."""
    src = str(getattr(getattr(shot, "info", None), "source", "") or "")
    p = Path(src) if src else None
    return p if p is not None and p.is_dir() else None


def read_record(shot_dir: str | Path) -> dict | None:
    """SHOT/truth/truth.json, or None when there is no truth apart."""
    f = Path(shot_dir) / TRUTH_DIR / RECORD
    if not f.is_file():
        return None
    try:
        doc = json.loads(f.read_text())
    except ValueError as exc:
        raise ValueError(f"{f}: not JSON ({exc})") from None
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise ValueError(f"{f}: field 'format' is {doc.get('format') if isinstance(doc, dict) else doc!r}, expected {FORMAT!r}")
    return doc


def label(record: dict | None) -> str:
    """'apart, 64 spp seed 1' for a truth apart, else `OWN`."""
    if record is None:
        return OWN
    return f"apart, {record['samples']} spp seed {record['seed']}"


def missing_frames(shot_dir: str | Path, num_frames: int) -> list[int]:
    return [t for t in range(num_frames) if not truth_frame_path(shot_dir, t).is_file()]


@dataclass
class Truth:
    """A shot's ground truth, frame by frame, linear (H, W, 3) float32 in the shot's Combined units."""

    shot: Any
    #: truth/truth.json when the truth apart is used, else None (the shot's rgb)
    record: dict | None = None
    folder: Path | None = None

    @property
    def apart(self) -> bool:
        return self.record is not None

    @property
    def label(self) -> str:
        return label(self.record)

    def frame(self, t: int) -> np.ndarray:
        if self.record is None:
            return self.shot.channel("rgb", t)
        from x2video.io.image import read_image

        f = truth_frame_path(self.folder, t)
        img = read_image(f)
        try:
            a = img.stack(["R", "G", "B"])
        except ValueError as exc:
            raise ValueError(f"{f} (truth frame {t}): {exc}") from None
        h, w = self.shot.size
        if a.shape[:2] != (h, w):
            raise ValueError(f"{f} (truth frame {t}): {a.shape[1]}x{a.shape[0]}, the shot is {w}x{h}")
        if not np.isfinite(a).all():
            raise ValueError(f"{f} (truth frame {t}): {int((~np.isfinite(a)).sum())} NaN/Inf value(s)")
        return a.astype(np.float32, copy=False)


def ground_truth(shot: Any, folder: str | Path | None = None) -> Truth:
    """The truth a shot is scored against: ``truth/`` beside its frames when it holds every frame, else its rgb.

    `folder`: the shot's folder (default `shot.info.source`); `shot` may be a view of its first frames, at its size.
    A truth apart that is there but unfinished, or of fewer frames or another size, is an error naming what is
    missing: mixing truths in one score is never silent."""
    d = Path(folder) if folder is not None else shot_folder(shot)
    rec = read_record(d) if d is not None else None
    if rec is None:
        return Truth(shot)
    n = int(rec.get("frames", -1))
    if n < shot.num_frames:  # a view of the shot's first frames reads fewer
        raise ValueError(f"{d / TRUTH_DIR / RECORD}: a truth of {n} frames, the shot has {shot.num_frames}")
    gone = missing_frames(d, n)
    if gone or not rec.get("complete"):
        first = gone[0] if gone else "?"
        raise ValueError(f"{d / TRUTH_DIR}: the truth apart is unfinished (frame {first} missing, {len(gone)} in all); finish it with"
                         f" `x2video dataset truth` or remove {d / TRUTH_DIR}")
    return Truth(shot, rec, d)


def summary(labels: Iterable[str]) -> str:
    """One line for a result's "truth" field: the label every shot shares, else each label with its count."""
    counts: dict[str, int] = {}
    for lab in labels:
        counts[lab] = counts.get(lab, 0) + 1
    if len(counts) == 1:
        return next(iter(counts))
    return "mixed: " + "; ".join(f"{k} ({v} shot{'s' if v != 1 else ''})" for k, v in counts.items())
