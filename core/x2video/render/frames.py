"""`FrameSink`: writes a render's `FramesReady` events to an MP4 file or an EXR folder, in frame order, atomically.

Recursive Sampling finishes frames out of order (keyframes first), so frames are staged on
disk in a hidden folder beside the output as they arrive (memory holds none of them) and
the output appears under its final name only when the render finishes: an MP4 is encoded
from the staged frames into a temporary file and renamed; an EXR folder is renamed into
place. Every staged frame is written atomically (temporary file, then rename), so a killed
process or a full disk leaves whole frames or none.

Without `resume`, a cancelled or failed render removes the staging folder and leaves no output.
With `resume` (a key of what makes the frames: `resume_key`), the staging folder has a fixed
name (`.OUT.resume`) and outlives a failed, cancelled or killed render; the next sink with the
same key takes its frames over (`kept`), so a re-run renders only what is missing
(`missing_runs`) and ends with the files an uninterrupted render writes. A staging folder made
with another key is removed. The same sink serves the editor's export (`x2video_app.state.exporter`), which
stages the edited channels beside the frames (`staging`). An existing output folder is replaced only when it
holds a render (frame files, `channels/`): a folder of other files is refused, never emptied. A full disk stops
the render with a `DiskFullError` naming the folder, the space the frames still to write need, and where the frames written so far are kept.
"""
from __future__ import annotations

import hashlib
import io
import json
import logging
import os
import shutil
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from x2video.io.atomic import DIR_MODE, DiskFullError, atomic_path, is_disk_full, looks_full, write_json_atomic
from x2video.io.units import OutputUnits
from x2video.render.events import FramesReady, RenderCancelled, RenderEvent, RenderFailed, RenderFinished

log = logging.getLogger(__name__)


RESUME_FORMAT = "x2video-render-resume"
#: the one folder an EXR render's output may hold beside its frames: the editor's edited channels (a shot folder)
CHANNELS_FOLDER = "channels"


def resume_key(**parts: Any) -> str:
    """A short digest of what decides a render's frames (settings, model options, output, the inputs' identity)."""
    return hashlib.sha256(json.dumps(parts, sort_keys=True, default=str).encode()).hexdigest()[:16]


def files_identity(path: str | Path) -> list[tuple[str, int, int]]:
    """(relative name, size, mtime in ns) of `path` or of every file below it: a re-run resumes only from frames made
    of the same input files (a shot re-rendered by Blender meanwhile starts over)."""
    root = Path(path)
    if root.is_file():
        st = root.stat()
        return [(root.name, st.st_size, st.st_mtime_ns)]
    out = []
    for d, _, names in os.walk(root):
        for n in names:
            p = Path(d) / n
            try:
                st = p.stat()
            except FileNotFoundError:
                continue
            out.append((str(p.relative_to(root)), st.st_size, st.st_mtime_ns))
    return sorted(out)


def _runs(frames: list[int]) -> list[tuple[int, int]]:
    """Sorted frame indices as [start, stop) runs of consecutive frames."""
    runs: list[tuple[int, int]] = []
    for f in frames:
        if runs and runs[-1][1] == f:
            runs[-1] = (runs[-1][0], f + 1)
        else:
            runs.append((f, f + 1))
    return runs


def _readable(path: Path) -> bool:
    """Whether a staged frame (an EXR, or an MP4's float16 .npy) reads whole."""
    try:
        if path.suffix == ".npy":
            a = np.load(path, mmap_mode="r")
            return a.ndim == 3 and a.shape[-1] == 3
        from x2video.io.image import read_image

        read_image(path)
        return True
    except (OSError, ValueError):
        return False


def _render_entry(p: Path) -> bool:
    """Whether `p`, in an existing output folder, is what a render writes there (a frame, the editor's channels)."""
    return (p.suffix == ".exr" and p.stem.isdigit()) or p.name == CHANNELS_FOLDER


def write_exr_frame(path: Path, rgb: np.ndarray, units: OutputUnits, *, in_units: bool = False) -> None:
    """Rendered linear RGB (H, W, 3) as a half-float EXR with channels R, G, B, in the input's units: the one layout of a
    rendered frame, written by `FrameSink` (the CLI, the editor's render) and the farm's chunks (`x2video.farm.chunks`).
    `in_units`: `rgb` is already in the input's units (the editor's exact frames over the shot's own), written as it is."""
    from x2video.io.image import write_exr

    rgb = np.asarray(rgb, np.float32) if in_units else units.scene(rgb)
    # no DateTime (OpenImageIO stamps the write's time otherwise): the same render writes the same bytes, so a resumed
    # render's files equal an uninterrupted one's
    write_exr(path, {"R": rgb[..., 0], "G": rgb[..., 1], "B": rgb[..., 2]}, "half", {**units.exr_attributes(), "DateTime": ""})


class FrameSink:
    """An `on_event` callback (or part of one) that writes finished frames to `out`.

    `out` ending in .mp4 gives an H.264 MP4 at `fps`; anything else is a folder of
    `000123.exr` files (shot frame numbers, linear half float, channels R, G, B).
    `expected` (the frame indices of the render), when given, is checked on finish.
    `units` (`x2video.io.units.OutputUnits`) takes the frames from the model's exposure to the
    input's units (EXR) and to the MP4's exposure; the default is the identity.
    `retry` ends a full disk's message when `resume` keeps the frames: what to do again to resume.
    """

    def __init__(self, out: str | Path, *, fps: float = 10.0, expected: list[int] | None = None,
                 units: OutputUnits | None = None, resume: str | None = None,
                 retry: str = "run the same command again") -> None:
        self.out = Path(out)
        self.units = units if units is not None else OutputUnits()
        if not fps > 0 or fps == float("inf"):
            raise ValueError(f"fps must be a positive number, got {fps}")
        self.fps = float(fps)
        self.expected = None if expected is None else sorted(expected)
        self.mp4 = self.out.suffix.lower() == ".mp4"
        parent = self.out.parent
        for p in (parent, *parent.parents):
            if p.exists():
                if not p.is_dir():
                    raise ValueError(f"output folder {parent} cannot be made: {p} is a file")
                break
        parent.mkdir(parents=True, exist_ok=True)  # `--out out/demo.mp4` on a fresh clone
        if self.out.exists() and self.mp4 == self.out.is_dir():
            kind = "a folder" if self.out.is_dir() else "a file"
            raise ValueError(f"output {self.out} exists and is {kind}")
        if not self.mp4 and self.out.is_dir():
            foreign = sorted(p.name for p in self.out.iterdir() if not _render_entry(p))
            if foreign:
                raise ValueError(f"output folder {self.out} holds other files ({', '.join(foreign[:3])}"
                                 f"{', ...' if len(foreign) > 3 else ''}); a render replaces its folder: pick an empty or new one")
        self.retry = retry
        self.resume = resume
        #: frames a failed earlier render with the same `resume` key left staged (whole files), taken over
        self.kept: set[int] = set()
        self._frames: set[int] = set()
        self.result: Path | None = None
        if resume is None:
            self._staging: Path | None = Path(tempfile.mkdtemp(prefix=f".{self.out.name}.", suffix=".partial", dir=parent))
        else:
            self._staging = self._take_over(parent / f".{self.out.name}.resume", resume)

    def _take_over(self, staging: Path, key: str) -> Path:
        """The fixed staging folder of a resumable render: an earlier one's frames when its key is `key`, else new."""
        record = staging / "resume.json"
        if staging.is_dir():
            try:
                doc = json.loads(record.read_text(encoding="utf-8"))
            except (OSError, ValueError):
                doc = None
            if isinstance(doc, dict) and doc.get("format") == RESUME_FORMAT and doc.get("key") == key:
                suffix = ".npy" if self.mp4 else ".exr"
                for p in staging.iterdir():
                    if p.name.startswith("."):  # a temporary a killed write left
                        p.unlink(missing_ok=True)
                    elif p.suffix == suffix and p.stem.isdigit():
                        if _readable(p):
                            self.kept.add(int(p.stem))
                        else:  # whole files only are renamed in, but a disk can still lie: render it again
                            log.warning("%s: staged frame %s does not read; it is rendered again", self.out, p)
                            p.unlink(missing_ok=True)
                if self.expected is not None:
                    self.kept &= set(self.expected)
                if self.kept:
                    log.info("%s: resuming, %d frame(s) kept from an earlier render in %s", self.out, len(self.kept), staging)
                return staging
            log.info("%s: removing %s (staged by a render with other settings or inputs)", self.out, staging)
            shutil.rmtree(staging, ignore_errors=True)
        staging.mkdir()
        write_json_atomic(record, {"format": RESUME_FORMAT, "key": key, "output": self.out.name})
        return staging

    @property
    def staging(self) -> Path:
        """The hidden folder that becomes `out` on `finish` (EXR): a writer of companion files (the editor's edited
        channels) stages them here, each atomically, so they appear and resume with the frames."""
        if self._staging is None:
            raise RuntimeError(f"frame sink for {self.out} is already closed")
        return self._staging

    def missing_runs(self) -> list[tuple[int, int]]:
        """The [start, stop) runs of `expected` frames not kept from an earlier render (all of them when none is)."""
        if self.expected is None:
            raise ValueError("missing_runs needs the expected frames")
        return _runs([f for f in self.expected if f not in self.kept])

    def _frame_path(self, index: int) -> Path:
        assert self._staging is not None
        return self._staging / (f"{index:06d}.npy" if self.mp4 else f"{index:06d}.exr")

    def __call__(self, event: RenderEvent) -> None:
        if isinstance(event, FramesReady):
            for index, rgb in event.frames.items():
                self.add(index, rgb, replace=index in event.replaces)
        elif isinstance(event, RenderFinished):
            if self.expected is None or set(self.expected) <= self._frames | self.kept or self.resume is None:
                self.finish()
            # else: a resumed render of the missing runs only; more renders follow (the caller finishes)
        elif isinstance(event, (RenderCancelled, RenderFailed)):
            self.abort()

    def add(self, index: int, rgb: np.ndarray, *, replace: bool = False, in_units: bool = False) -> None:
        """Stage one linear RGB (H, W, 3) frame; `replace` allows (and requires) an earlier frame `index`; `in_units`:
        the frame is already in the input's units (EXR only: an MP4 takes the model's exposure)."""
        if in_units and self.mp4:
            raise ValueError(f"{self.out}: frames in the input's units go to an EXR folder, not an MP4")
        if self._staging is None:
            raise RuntimeError(f"frame sink for {self.out} is already closed")
        if index in self._frames and not replace:
            raise ValueError(f"frame {index} arrived twice")
        if replace and index not in self._frames:
            raise ValueError(f"frame {index} arrived as a replacement of a frame that never arrived")
        if index in self.kept and not replace:  # staged by the earlier render with the same key: the same frame
            self._frames.add(index)
            return
        try:
            with atomic_path(self._frame_path(index)) as tmp:
                if self.mp4:
                    buf = io.BytesIO()
                    np.save(buf, np.asarray(rgb, dtype=np.float16))
                    with open(tmp, "wb") as f:  # a Python write: a full disk raises ENOSPC (numpy's own write says only bytes)
                        f.write(buf.getbuffer())
                else:
                    write_exr_frame(tmp, rgb, self.units, in_units=in_units)
        except OSError as exc:
            if is_disk_full(exc) or looks_full(self._staging, np.asarray(rgb).size * 2):
                raise self.disk_full(f"frame {index}", rgb) from None
            raise
        self._frames.add(index)

    def disk_full(self, what: str, rgb: np.ndarray | None = None) -> DiskFullError:
        """The error of a full disk while staging `what`: the space the frames still to write need (the mean staged
        frame's size, or the frame's raw size before any is staged) and what is kept."""
        assert self._staging is not None
        staged = [p for p in self._staging.iterdir() if p.name[:1].isdigit()]
        sizes = [p.stat().st_size for p in staged]
        each = (sum(sizes) / len(sizes)) if sizes else (0 if rgb is None else np.asarray(rgb).size * 2)
        left = [f for f in (self.expected or []) if f not in self._frames and f not in self.kept] or [None]
        need = int(each * len(left))
        if self.mp4:
            need += int(each * len(self.expected or staged) / 4)  # the encoded MP4: at most 8-bit 4:2:0 (1/4 of the float16 frames)
        if self.resume is not None:
            kept = f"the {len(staged)} frame(s) written are kept in {self._staging}; free space and {self.retry} to resume"
        else:
            kept = f"nothing was written to {self.out}"
        n = len(left) if left != [None] else 1
        return DiskFullError(self.out.parent, need, what=f"writing {what} of {self.out.name}, {n} frame(s) still to write", kept=kept)

    def finish(self) -> Path:
        """Write the output under its final name; returns it."""
        if self._staging is None:
            raise RuntimeError(f"frame sink for {self.out} is already closed")
        order = sorted(self._frames | self.kept)
        try:
            if not order:
                raise ValueError(f"no frames were rendered for {self.out}")
            if self.expected is not None and order != self.expected:
                missing = sorted(set(self.expected) - set(order))
                raise ValueError(f"render for {self.out} is missing frames {missing[:10]}")
            if self.mp4:
                from x2video.io.writers import MP4Writer

                try:
                    with MP4Writer(self.out, self.fps, encode="srgb") as video:  # atomic; pads odd sizes
                        for i in order:
                            video.write(self.units.display(np.load(self._frame_path(i)).astype(np.float32)))
                except OSError as exc:
                    if not (is_disk_full(exc) or looks_full(self.out.parent, 1 << 16)):
                        raise
                    h, w = np.load(self._frame_path(order[0]), mmap_mode="r").shape[:2]
                    raise DiskFullError(self.out.parent, int(h * w * 1.5 * len(order)), at_most=True,  # 8-bit 4:2:0, uncompressed
                                        what=f"encoding {self.out.name} from {len(order)} frames",
                                        kept=(f"the staged frames are kept in {self._staging}; free space and {self.retry} "
                                              "to encode them" if self.resume is not None else f"nothing was written to {self.out}")
                                        ) from None
            else:
                (self._staging / "resume.json").unlink(missing_ok=True)
                self._replace_folder()
        except BaseException:
            self.abort()
            raise
        self._remove_staging()  # removes what is left of the staging folder
        self.result = self.out
        log.info("wrote %d frames to %s", len(order), self.out)
        return self.out

    def _replace_folder(self) -> None:
        assert self._staging is not None
        old = None
        if self.out.exists():
            old = Path(tempfile.mkdtemp(prefix=f".{self.out.name}.", suffix=".old", dir=self.out.parent))
            os.replace(self.out, old / "previous")
        os.chmod(self._staging, DIR_MODE)  # mkdtemp made it 0700: a shared render folder must be readable by others
        os.replace(self._staging, self.out)
        self._staging = None
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)

    def abort(self) -> None:
        """Nothing appears under the output name; what was staged is dropped, or, with `resume`, kept for the next
        render with the same key (whole frames only: each was written atomically)."""
        if self._staging is not None and self.resume is not None and self.result is None:
            if not any(p.name[:1].isdigit() for p in self._staging.iterdir()):  # nothing to resume from
                self._remove_staging()
                return
            if self._frames - self.kept:
                log.info("%s: %d frame(s) kept in %s for a re-run to resume from", self.out, len(self._frames | self.kept), self._staging)
            self._staging = None
            return
        self._remove_staging()

    def _remove_staging(self) -> None:
        if self._staging is not None:
            shutil.rmtree(self._staging, ignore_errors=True)
            self._staging = None

    def __enter__(self) -> "FrameSink":
        return self

    def __exit__(self, *exc: object) -> None:
        self.abort()
