"""Content-keyed cache of per-frame conditioning latents (`RenderModel.encode_frames` outputs).

The key hashes what `encode_frames` reads from a `FrameConditioning` — the five intrinsic
channels (or their absence) and the A|M|R union mask — plus `model.content_key()`. Local
prompt masks, prompts and the frame index are not part of it: they do not enter the
conditioning latents, so a re-render after a prompt-only change re-encodes nothing.
Thread-safe; least recently used entries are evicted beyond `max_bytes`. A Renderer made with
`retain=False` (the CLI, farm workers: one render each) drops a frame's entries after the last window
that reads them, so a long shot holds only the frames still ahead (issue 31: 0.8 MB a frame at 320x224,
the conditioning latents and the half-precision detail).
"""
from __future__ import annotations

import hashlib
import threading
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np
import torch

from x2video.channels import INTRINSIC
from x2video.conditioning.frame import FrameConditioning


@dataclass(frozen=True)
class CacheStats:
    """Counters since the cache was made (or `reset_stats`)."""

    hits: int
    misses: int
    entries: int
    bytes: int


def _feed(h: "hashlib._Hash", name: str, arr: np.ndarray | None) -> None:
    h.update(name.encode())
    if arr is None:
        h.update(b"<dropped>")
        return
    a = np.ascontiguousarray(arr)
    h.update(f"{a.dtype.str}{a.shape}".encode())
    h.update(memoryview(a).cast("B"))


def conditioning_key(cond: FrameConditioning, model_key: str) -> str:
    """Hex digest identifying the conditioning latents of one frame for one set of weights."""
    h = hashlib.blake2b(digest_size=20)
    h.update(model_key.encode())
    for name in INTRINSIC:
        _feed(h, name, cond.channels.get(name))
    _feed(h, "amr_mask", cond.amr_mask)
    return h.hexdigest()


class ConditioningCache:
    """LRU map conditioning key -> (C_cond, h, w) latent tensor."""

    def __init__(self, max_bytes: int = 1 << 30) -> None:
        self.max_bytes = int(max_bytes)
        self._items: OrderedDict[str, torch.Tensor] = OrderedDict()
        self._bytes = 0
        self._hits = 0
        self._misses = 0
        self._lock = threading.Lock()

    def get(self, key: str) -> torch.Tensor | None:
        with self._lock:
            value = self._items.get(key)
            if value is None:
                self._misses += 1
                return None
            self._items.move_to_end(key)
            self._hits += 1
            return value

    def put(self, key: str, value: torch.Tensor) -> None:
        size = value.numel() * value.element_size()
        with self._lock:
            old = self._items.pop(key, None)
            if old is not None:
                self._bytes -= old.numel() * old.element_size()
            self._items[key] = value
            self._bytes += size
            while self._bytes > self.max_bytes and len(self._items) > 1:
                _, dropped = self._items.popitem(last=False)
                self._bytes -= dropped.numel() * dropped.element_size()

    def discard(self, keys: "list[str]") -> None:
        """Drop `keys` (absent ones are ignored): a render that keeps nothing for re-renders
        (`Renderer(retain=False)`) drops each frame's entries after their last use."""
        with self._lock:
            for key in keys:
                old = self._items.pop(key, None)
                if old is not None:
                    self._bytes -= old.numel() * old.element_size()

    def stats(self) -> CacheStats:
        with self._lock:
            return CacheStats(self._hits, self._misses, len(self._items), self._bytes)

    def reset_stats(self) -> None:
        with self._lock:
            self._hits = self._misses = 0

    def clear(self) -> None:
        with self._lock:
            self._items.clear()
            self._bytes = 0
