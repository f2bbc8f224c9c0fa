"""A small bounded LRU cache of decoded frames, so a shot never holds more than a few in memory."""
from __future__ import annotations

import threading
from collections import OrderedDict
from typing import Callable, Hashable, TypeVar

V = TypeVar("V")


class LRU:
    """Least-recently-used cache holding at most `capacity` values (0 disables caching).

    Thread-safe (the editor's render and propagation workers read a shot while the viewer does);
    `make()` runs outside the lock, so two threads may both make a missing value."""

    def __init__(self, capacity: int = 24):
        if capacity < 0:
            raise ValueError(f"cache capacity must be >= 0, got {capacity}")
        self.capacity = capacity
        self._data: OrderedDict[Hashable, object] = OrderedDict()
        self._lock = threading.Lock()

    def __len__(self) -> int:
        return len(self._data)

    def __contains__(self, key: Hashable) -> bool:
        return key in self._data

    def get_or(self, key: Hashable, make: Callable[[], V]) -> V:
        """The cached value for `key`, or `make()` stored (evicting the oldest past capacity)."""
        with self._lock:
            if key in self._data:
                self._data.move_to_end(key)
                return self._data[key]  # type: ignore[return-value]
        value = make()
        if self.capacity:
            with self._lock:
                self._data[key] = value
                while len(self._data) > self.capacity:
                    self._data.popitem(last=False)
        return value

    def clear(self) -> None:
        with self._lock:
            self._data.clear()
