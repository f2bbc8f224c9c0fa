"""How long the GUI thread's event loop waits: the gaps between a 10 ms QTimer's ticks, with the process's CPU time in each.

A gap longer than the interval means the event loop could not run: the GUI thread computed, waited for a lock (the
GIL a worker holds), or the operating system ran other processes. The CPU time the process got during the gap tells
the last apart: on a machine loaded by other work (a data build at a higher priority) a gap of 600 ms can hold 10 ms
of this process's CPU, which no code of ours could have spent blocking the GUI. `busy` gaps are min(wall gap,
process CPU time in it): the part of each gap this process was running; they equal the wall gaps on a quiet machine.
"""
from __future__ import annotations

import time

import numpy as np
from PySide6.QtCore import QObject, QTimer


class TickProbe(QObject):
    """Records (wall clock, process CPU, GUI-thread CPU) at each tick of a QTimer on the GUI thread."""

    def __init__(self, interval_ms: int = 10, parent: QObject | None = None) -> None:
        super().__init__(parent)
        self.interval_ms = interval_ms
        self.ticks: list[tuple[float, float, float]] = []
        self._timer = QTimer(self)
        self._timer.setInterval(interval_ms)
        self._timer.timeout.connect(lambda: self.ticks.append((time.perf_counter(), time.process_time(), time.thread_time())))

    def start(self) -> None:
        self.ticks.clear()
        self._timer.start()

    def stop(self) -> None:
        self._timer.stop()

    def gaps_ms(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(wall gaps, busy gaps, the GUI thread's own CPU in each gap), milliseconds."""
        if len(self.ticks) < 2:
            return np.zeros(0), np.zeros(0), np.zeros(0)
        d = np.diff(np.asarray(self.ticks), axis=0) * 1000.0
        return d[:, 0], np.minimum(d[:, 0], d[:, 1]), d[:, 2]

    def summary(self) -> dict:
        """Tick count and median / 95th percentile / max of the wall gaps, the busy gaps and the GUI thread's CPU."""
        wall, busy, gui = self.gaps_ms()
        if not wall.size:
            return {"ticks": len(self.ticks)}

        def stats(a: np.ndarray) -> dict:
            return {"median": round(float(np.median(a)), 1), "p95": round(float(np.percentile(a, 95)), 1), "max": round(float(a.max()), 1)}

        return {"ticks": len(self.ticks), "interval_ms": self.interval_ms, **stats(wall), "busy": stats(busy), "gui_thread_cpu": stats(gui)}
