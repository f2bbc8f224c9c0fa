"""`FrameSink`: writes a render's `FramesReady` events to an MP4 file or an EXR folder, in frame order, atomically.

Recursive Sampling finishes frames out of order (keyframes first), so frames are staged on
disk in a hidden folder beside the output as they arrive (memory holds none of them) and
the output appears under its final name only when the render finishes: an MP4 is encoded
from the staged frames into a temporary file and renamed; an EXR folder is renamed into
place. A cancelled or failed render removes the staging folder and leaves no output.
"""
from __future__ import annotations

import logging
import os
import shutil
import tempfile
from pathlib import Path

import numpy as np

from x2video.io.atomic import DIR_MODE
from x2video.io.units import OutputUnits
from x2video.sampling.events import FramesReady, RenderCancelled, RenderEvent, RenderFailed, RenderFinished

log = logging.getLogger(__name__)


def _write_exr(path: Path, rgb: np.ndarray, units: OutputUnits) -> None:
    """Rendered linear RGB (H, W, 3) as a half-float EXR with channels R, G, B, in the input's units."""
    from x2video.io.image import write_exr

    rgb = units.scene(rgb)
    write_exr(path, {"R": rgb[..., 0], "G": rgb[..., 1], "B": rgb[..., 2]}, "half", units.exr_attributes())


class FrameSink:
    """An `on_event` callback (or part of one) that writes finished frames to `out`.

    `out` ending in .mp4 gives an H.264 MP4 at `fps`; anything else is a folder of
    `000123.exr` files (shot frame numbers, linear half float, channels R, G, B).
    `expected` (the frame indices of the render), when given, is checked on finish.
    `units` (`x2video.io.units.OutputUnits`) takes the frames from the model's exposure to the
    input's units (EXR) and to the MP4's exposure; the default is the identity.
    """

    def __init__(self, out: str | Path, *, fps: float = 10.0, expected: list[int] | None = None,
                 units: OutputUnits | None = None) -> None:
        self.out = Path(out)
        self.units = units if units is not None else OutputUnits()
        self.fps = float(fps)
        self.expected = None if expected is None else sorted(expected)
        self.mp4 = self.out.suffix.lower() == ".mp4"
        parent = self.out.parent
        if parent.exists() and not parent.is_dir():
            raise NotADirectoryError(f"output folder {parent} is a file")
        parent.mkdir(parents=True, exist_ok=True)  # `--out out/demo.mp4` on a fresh clone
        if self.out.exists() and self.mp4 == self.out.is_dir():
            kind = "a folder" if self.out.is_dir() else "a file"
            raise ValueError(f"output {self.out} exists and is {kind}")
        self._staging: Path | None = Path(tempfile.mkdtemp(prefix=f".{self.out.name}.", suffix=".partial", dir=parent))
        self._frames: set[int] = set()
        self.result: Path | None = None

    def _frame_path(self, index: int) -> Path:
        assert self._staging is not None
        return self._staging / (f"{index:06d}.npy" if self.mp4 else f"{index:06d}.exr")

    def __call__(self, event: RenderEvent) -> None:
        if isinstance(event, FramesReady):
            for index, rgb in event.frames.items():
                self.add(index, rgb, replace=index in event.replaces)
        elif isinstance(event, RenderFinished):
            self.finish()
        elif isinstance(event, (RenderCancelled, RenderFailed)):
            self.abort()

    def add(self, index: int, rgb: np.ndarray, *, replace: bool = False) -> None:
        """Stage one linear RGB (H, W, 3) frame; `replace` allows (and requires) an earlier frame `index`."""
        if self._staging is None:
            raise RuntimeError(f"frame sink for {self.out} is already closed")
        if index in self._frames and not replace:
            raise ValueError(f"frame {index} arrived twice")
        if replace and index not in self._frames:
            raise ValueError(f"frame {index} arrived as a replacement of a frame that never arrived")
        if self.mp4:
            np.save(self._frame_path(index), np.asarray(rgb, dtype=np.float16))
        else:
            _write_exr(self._frame_path(index), rgb, self.units)
        self._frames.add(index)

    def finish(self) -> Path:
        """Write the output under its final name; returns it."""
        if self._staging is None:
            raise RuntimeError(f"frame sink for {self.out} is already closed")
        order = sorted(self._frames)
        try:
            if not order:
                raise ValueError(f"no frames were rendered for {self.out}")
            if self.expected is not None and order != self.expected:
                missing = sorted(set(self.expected) - set(order))
                raise ValueError(f"render for {self.out} is missing frames {missing[:10]}")
            if self.mp4:
                from x2video.io.writers import MP4Writer

                with MP4Writer(self.out, self.fps, encode="srgb") as video:  # atomic; pads odd sizes
                    for i in order:
                        video.write(self.units.display(np.load(self._frame_path(i)).astype(np.float32)))
            else:
                self._replace_folder()
        except BaseException:
            self.abort()
            raise
        self.abort()  # removes what is left of the staging folder
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
        """Drop everything staged; nothing appears under the output name."""
        if self._staging is not None:
            shutil.rmtree(self._staging, ignore_errors=True)
            self._staging = None

    def __enter__(self) -> "FrameSink":
        return self

    def __exit__(self, *exc: object) -> None:
        self.abort()
