"""A tiny Qt-free signal (napari/psygnal style) so the editor's state model can be observed without Qt."""
from __future__ import annotations

import logging
from typing import Any, Callable

log = logging.getLogger(__name__)


class Signal:
    """Callbacks connected to it are called in order with the emitted arguments.

    It is deliberately synchronous and single-threaded: the state model lives on the GUI
    thread and the render worker never touches it directly (its events reach the GUI thread
    through a Qt signal first).
    """

    def __init__(self, name: str = "") -> None:
        self.name = name
        self._slots: list[Callable[..., Any]] = []
        self._blocked = 0

    def connect(self, slot: Callable[..., Any]) -> Callable[..., Any]:
        if slot not in self._slots:
            self._slots.append(slot)
        return slot

    def disconnect(self, slot: Callable[..., Any]) -> None:
        if slot in self._slots:
            self._slots.remove(slot)

    def emit(self, *args: Any) -> None:
        if self._blocked:
            return
        for slot in list(self._slots):
            slot(*args)

    class _Blocker:
        def __init__(self, sig: "Signal") -> None:
            self.sig = sig

        def __enter__(self) -> None:
            self.sig._blocked += 1

        def __exit__(self, *exc: Any) -> None:
            self.sig._blocked -= 1

    def blocked(self) -> "Signal._Blocker":
        """Context manager that suppresses emission (for batched updates)."""
        return Signal._Blocker(self)
