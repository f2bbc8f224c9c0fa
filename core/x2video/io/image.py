"""Single-image read/write through OpenImageIO (EXR, PNG 8/16-bit, JPG, TIFF), channels indexed by name.

OpenImageIO stores EXR channels sorted by layer name, so nothing here relies on channel order:
`ImageData.channel(name)` / `ImageData.stack(names)` look channels up by name.
Integer pixel formats of PNG/JPG/TIFF are normalised to [0, 1] (``ImageData.max_int`` tells the
scale, for object ids); 32-bit integer EXR channels are read raw.

`read_image(path, channels=...)` reads only the named channels of an EXR, in one pass through OpenEXR's own
Python bindings (OpenImageIO reads a contiguous channel range per call, and each call decompresses the file
again). A Blender multi-layer frame holds every light pass: 70 channels at 1024x768, 0.65-1.1 s to read whole
with OpenImageIO, 0.29 s for the 22 a shot uses (`x2video.io.multilayer`). Without the bindings, or for a file
they cannot read, the whole image is read through OpenImageIO as before.
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np

from x2video.io.atomic import DiskFullError, atomic_path, free_bytes


class _Missing:
    """Stands in for a module that is not installed: importing x2video still works (a lent GPU image has
    no OpenImageIO), and the first image read or write says what is missing."""

    def __init__(self, name: str, error: ImportError) -> None:
        self._name, self._error = name, error

    def __getattr__(self, attr: str) -> Any:
        raise ImportError(f"{self._name} is not installed ({self._error}); reading and writing images needs it "
                          "(`pip install OpenImageIO`, as scripts/setup.sh does)")


try:
    import OpenImageIO as oiio
except ImportError as _e:
    oiio = _Missing("OpenImageIO", _e)

IMAGE_EXTENSIONS = (".exr", ".png", ".jpg", ".jpeg", ".tif", ".tiff")
_RAW_INT = ("uint", "int", "uint32", "int32")
_FORMATS = {"half": "half", "float": "float", "uint": "uint", "uint8": "uint8", "uint16": "uint16"}


class ImageReadError(ValueError):
    """An image file could not be read (missing, corrupt, truncated, unsupported)."""


@dataclass
class ImageData:
    """One image: per-channel (H, W) arrays keyed by the file's channel names."""

    path: str
    width: int
    height: int
    channel_names: tuple[str, ...]
    planes: dict[str, np.ndarray]
    #: pixel format of the file's first channel ("half", "float", "uint8", "uint16", "uint", ...)
    format: str
    #: 255 / 65535 for 8/16-bit integer files (values were divided by it), None for float/raw-int
    max_int: int | None = None
    attributes: dict[str, Any] = field(default_factory=dict)

    def channel(self, name: str) -> np.ndarray:
        """(H, W) plane of channel `name`."""
        try:
            return self.planes[name]
        except KeyError:
            if name in self.channel_names:  # `read_image(..., channels=...)` read others only
                raise ImageReadError(f"{self.path}: channel {name!r} was not read (read_image read {', '.join(self.planes)})") from None
            raise ImageReadError(f"{self.path}: no channel {name!r} (has {', '.join(self.channel_names)})") from None

    def stack(self, names: Sequence[str], dtype: Any = np.float32) -> np.ndarray:
        """(H, W, len(names)) array of the named channels, in the order asked."""
        return np.stack([self.channel(n) for n in names], axis=-1).astype(dtype, copy=False)

    def all(self) -> np.ndarray:
        """(H, W, C) float32 array of all channels read, in file order."""
        return self.stack([n for n in self.channel_names if n in self.planes])


class ShotChangedError(ImageReadError):
    """A frame's file vanished or changed after its shot was opened (another program re-rendering the shot while we
    read it): the render stops naming the file and frame instead of mixing old and new frames."""


def _stamp(path: str | Path) -> tuple[int, int, int]:
    st = os.stat(path)
    return st.st_size, st.st_mtime_ns, st.st_ino


class FileStamps:
    """Size, modification time and inode of a shot's frame files when it was opened; `read` reads one of them checked
    against its stamp before and after the read, so a file deleted, truncated or rewritten (in place or by a rename)
    while a render reads the shot is a `ShotChangedError` naming the file and frame, never a silently different frame."""

    def __init__(self, paths: Sequence[str | Path]) -> None:
        self._stamps: dict[str, tuple[int, int, int]] = {}
        for p in paths:
            try:
                self._stamps[str(p)] = _stamp(p)
            except FileNotFoundError:
                raise ImageReadError(f"{p}: file does not exist (it vanished while the shot was being opened)") from None

    def read(self, path: str | Path, where: str, channels: Sequence[str] | None = None, reader: Any = None) -> ImageData:
        """`read_image(path, channels)` (or `reader`'s); `where` (e.g. "frame 12") goes into every error."""
        key = str(path)
        want = self._stamps.get(key)
        self._check(path, where, want, "before it was read")
        reader = reader if reader is not None else read_image
        try:
            img = reader(path) if channels is None else reader(path, channels=channels)
        except ImageReadError as exc:
            self._check(path, where, want, "while it was read")  # a half-written file: say that it changed, not only "corrupt"
            raise ImageReadError(f"{exc} ({where})") from None
        self._check(path, where, want, "while it was read")
        return img

    def _check(self, path: str | Path, where: str, want: tuple[int, int, int] | None, when: str) -> None:
        try:
            now = _stamp(path)
        except FileNotFoundError:
            raise ShotChangedError(f"{path} ({where}): the file was removed after the shot was opened ({when}); "
                                   "restore it, or open the shot again") from None
        if want is not None and now != want:
            import time

            changed = time.strftime("%H:%M:%S", time.localtime(now[1] / 1e9))
            raise ShotChangedError(f"{path} ({where}): the file changed after the shot was opened (rewritten at {changed}, "
                                   f"{now[0]} bytes, was {want[0]}; noticed {when}); another program may be writing the shot: "
                                   "open it again when it has finished")


def read_spec(path: str | Path) -> oiio.ImageSpec:
    """The header of an image (size, channel names) without reading pixels."""
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        raise ImageReadError(f"{path}: cannot open image ({oiio.geterror() or 'unknown error'})")
    try:
        return inp.spec().copy()
    finally:
        inp.close()


def read_image(path: str | Path, channels: Sequence[str] | None = None) -> ImageData:
    """Read the channels of the first subimage of `path`: all of them, or for an EXR at least `channels` (only
    those when OpenEXR's bindings can read them; `ImageData.channel_names` lists the file's channels either way)."""
    path = str(path)
    if not Path(path).is_file():
        raise ImageReadError(f"{path}: file does not exist")
    if channels is not None and path.lower().endswith(".exr"):
        img = _read_exr_channels(path, channels)
        if img is not None:
            return img
    inp = oiio.ImageInput.open(path)
    if inp is None:
        raise ImageReadError(f"{path}: cannot open image ({oiio.geterror() or 'unknown error'})")
    try:
        spec = inp.spec()
        n = spec.nchannels
        names = tuple(spec.channelnames) if spec.channelnames else tuple(f"c{i}" for i in range(n))
        formats = [str(spec.channelformat(i)) for i in range(n)]
        pixels = inp.read_image(0, 0, 0, n, "float")
        if pixels is None:
            raise ImageReadError(f"{path}: cannot read pixels ({inp.geterror() or 'corrupt or truncated file'})")
        pixels = np.asarray(pixels, dtype=np.float32).reshape(spec.height, spec.width, n)
        planes = {name: pixels[..., i] for i, name in enumerate(names)}
        is_exr = path.lower().endswith(".exr")
        for i, fmt in enumerate(formats):
            if is_exr and fmt in _RAW_INT:
                raw = inp.read_image(0, 0, i, i + 1, fmt)
                if raw is None:
                    raise ImageReadError(f"{path}: cannot read channel {names[i]!r} ({inp.geterror()})")
                planes[names[i]] = np.asarray(raw).reshape(spec.height, spec.width)
        max_int = {"uint8": 255, "uint16": 65535, "int8": 127, "int16": 32767}.get(formats[0]) if not is_exr else None
        attrs = {}
        for p in spec.extra_attribs:
            if p.name.startswith("x2video:") or p.name in ("framesPerSecond", "oiio:ColorSpace"):
                attrs[p.name] = p.value
        return ImageData(path, spec.width, spec.height, names, planes, formats[0], max_int, attrs)
    finally:
        inp.close()


def _read_exr_channels(path: str, channels: Sequence[str]) -> ImageData | None:
    """`channels` of an EXR in one pass (OpenEXR's bindings), float channels as float32 and 32-bit integer ones raw;
    None when the bindings are missing or cannot read the file or a channel (the caller reads it all through
    OpenImageIO, which also says what is wrong with a broken file)."""
    try:
        import Imath
        import OpenEXR
    except ImportError:
        return None
    spec = read_spec(path)
    names = tuple(spec.channelnames)
    want = list(dict.fromkeys(channels))
    if not want or any(c not in names for c in want):
        return None
    try:
        f = OpenEXR.InputFile(path)
    except Exception:  # noqa: BLE001  (not readable by the bindings: OpenImageIO's path decides)
        return None
    try:
        header = f.header()
        dw = header["dataWindow"]
        w, h = dw.max.x - dw.min.x + 1, dw.max.y - dw.min.y + 1
        if (w, h) != (spec.width, spec.height):
            return None
        raw = [c for c in want if header["channels"][c].type.v == Imath.PixelType.UINT]  # ids: read raw, as below
        planes = {}
        for group, kind, dtype in ((raw, Imath.PixelType.UINT, np.uint32), ([c for c in want if c not in raw], Imath.PixelType.FLOAT, np.float32)):
            if group:  # one pass over the file per group
                for c, buf in zip(group, f.channels(group, Imath.PixelType(kind))):
                    planes[c] = np.frombuffer(buf, dtype).reshape(h, w).copy()
    except Exception:  # noqa: BLE001
        return None
    finally:
        f.close()
    attrs = {p.name: p.value for p in spec.extra_attribs if p.name.startswith("x2video:") or p.name in ("framesPerSecond", "oiio:ColorSpace")}
    return ImageData(path, spec.width, spec.height, names, planes, str(spec.channelformat(0)), None, attrs)


def write_exr(
    path: str | Path,
    planes: Mapping[str, np.ndarray],
    pixel_type: str | Mapping[str, str] = "half",
    attributes: Mapping[str, Any] | None = None,
    compression: str = "zip",
) -> None:
    """Write named (H, W) planes as one EXR, atomically.

    pixel_type: "half" | "float" | "uint" for all channels, or a per-channel mapping. "uint"
    channels are written raw (no normalisation); a file mixing "uint" with float types is
    written as separate raw passes, so keep ids in their own file or store them as "float".
    """
    names = list(planes)
    if not names:
        raise ValueError(f"{path}: no channels to write")
    arrays = [np.asarray(planes[n]) for n in names]
    h, w = arrays[0].shape[:2]
    for n, a in zip(names, arrays):
        if a.shape != (h, w):
            raise ValueError(f"{path}: channel {n!r} has shape {a.shape}, expected {(h, w)}")
    types = [pixel_type] * len(names) if isinstance(pixel_type, str) else [pixel_type.get(n, "half") for n in names]
    for t in types:
        if t not in ("half", "float", "uint"):
            raise ValueError(f"{path}: unknown EXR pixel type {t!r}")
    if "uint" in types and len(set(types)) > 1:
        raise ValueError(f"{path}: cannot mix raw 'uint' channels with float ones in one file; store ids as 'float'")
    spec = oiio.ImageSpec(w, h, len(names), oiio.TypeDesc(types[0]))
    spec.channelnames = tuple(names)
    if len(set(types)) > 1:
        spec.channelformats = tuple(oiio.TypeDesc(t) for t in types)
    spec.attribute("compression", compression)
    for k, v in (attributes or {}).items():
        spec.attribute(k, v)
    if types[0] == "uint":
        data = np.ascontiguousarray(np.stack(arrays, -1).astype(np.uint32))
    else:
        data = np.ascontiguousarray(np.stack(arrays, -1).astype(np.float32))
    _write(path, spec, data)


def write_ldr(path: str | Path, pixels: np.ndarray, bits: int = 8) -> None:
    """Write an (H, W, C) array of values in [0, 1] as an 8- or 16-bit PNG/JPG/TIFF, atomically.

    Integer arrays (uint8/uint16) are written as they are.
    """
    a = np.asarray(pixels)
    if a.ndim == 2:
        a = a[..., None]
    if a.dtype == np.uint8:
        data, fmt = a, "uint8"
    elif a.dtype == np.uint16:
        data, fmt = a, "uint16"
    else:
        if bits not in (8, 16):
            raise ValueError(f"{path}: bits must be 8 or 16, got {bits}")
        maxv = 255 if bits == 8 else 65535
        data = np.round(np.clip(a.astype(np.float32), 0.0, 1.0) * maxv).astype(np.uint8 if bits == 8 else np.uint16)
        fmt = "uint8" if bits == 8 else "uint16"
    h, w, c = data.shape
    spec = oiio.ImageSpec(w, h, c, oiio.TypeDesc(fmt))
    if c == 1:
        spec.channelnames = ("Y",)
    _write(path, spec, np.ascontiguousarray(data))


def _write_failed(path: str | Path, data: np.ndarray, detail: str) -> OSError:
    """The error of a failed OpenImageIO write: OpenImageIO reports no errno, so a write that failed with less space
    free than the image's uncompressed size counts as a full disk (`DiskFullError`, naming the folder)."""
    folder = Path(path).parent
    free = free_bytes(folder)
    if free is not None and free < data.nbytes + 4096:
        return DiskFullError(folder, data.nbytes, what=f"writing {Path(path).name}", at_most=True)
    return OSError(f"{path}: write failed ({detail})")


def _write(path: str | Path, spec: oiio.ImageSpec, data: np.ndarray) -> None:
    with atomic_path(path) as tmp:
        out = oiio.ImageOutput.create(str(tmp))
        if out is None:
            raise ValueError(f"{path}: no image writer for this extension ({oiio.geterror()})")
        closed = False
        try:
            if not out.open(str(tmp), spec):
                raise _write_failed(path, data, f"cannot open for writing: {out.geterror()}")
            if not out.write_image(data):
                raise _write_failed(path, data, out.geterror())
            closed = True
            if not out.close():  # the last of the file is flushed here: a full disk can fail it too
                raise _write_failed(path, data, f"cannot finish the file: {out.geterror()}")
        finally:
            if not closed:
                out.close()
        _check_written(tmp, path, data)


def _check_written(tmp: Path, path: str | Path, data: np.ndarray) -> None:
    """OpenImageIO reports success for an image the disk had no room for (found with a full tmpfs: a 17 KB EXR
    written as its first 16 KB, write_image and close both True). On a nearly full disk (less free than twice the
    file, plus 1 MB) read the file back; a file that does not read is a `DiskFullError`, and no file is left."""
    free = free_bytes(tmp.parent)
    if free is None or free >= 2 * tmp.stat().st_size + (1 << 20):
        return
    inp = oiio.ImageInput.open(str(tmp))
    ok = inp is not None and inp.read_image(0, 0, 0, inp.spec().nchannels, "float") is not None
    if inp is not None:
        inp.close()
    if not ok:
        raise DiskFullError(Path(path).parent, data.nbytes, what=f"writing {Path(path).name}, cut short", at_most=True)
