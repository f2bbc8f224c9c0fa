"""pyqtgraph charts: seconds per window of the current render (by level), and speed vs accuracy from bench results."""
from __future__ import annotations

import json
import logging
from pathlib import Path
from typing import Any

import pyqtgraph as pg
from PySide6.QtCore import Qt
from PySide6.QtWidgets import QLabel, QTabWidget, QVBoxLayout, QWidget

from x2video.eval.report import labels_below
from x2video_app.timeline import level_colour

log = logging.getLogger(__name__)

_SPEED_KEYS = ("seconds_per_frame", "sec_per_frame", "s_per_frame", "spf")
_ACC_KEYS = ("psnr", "PSNR")
_LABEL_KEYS = ("name", "label", "preset", "setting", "config")


def find_bench_points(obj: Any, source: str = "") -> list[tuple[str, float, float]]:
    """Every dict inside a bench results JSON that has a seconds-per-frame and a PSNR field.

    Returns (label, seconds_per_frame, psnr) triples. The walk is structural so it reads
    both a flat list of rows and nested {"setting": {...}} tables.
    """
    out: list[tuple[str, float, float]] = []

    def walk(o: Any, path: str) -> None:
        if isinstance(o, dict):
            speed = next((o[k] for k in _SPEED_KEYS if isinstance(o.get(k), (int, float))), None)
            acc = next((o[k] for k in _ACC_KEYS if isinstance(o.get(k), (int, float))), None)
            if speed is not None and acc is not None:
                label = next((str(o[k]) for k in _LABEL_KEYS if k in o), path or source)
                out.append((label, float(speed), float(acc)))
            for k, v in o.items():
                walk(v, f"{path}/{k}" if path else str(k))
        elif isinstance(o, list):
            for i, v in enumerate(o):
                walk(v, f"{path}[{i}]")

    walk(obj, "")
    return out


def load_bench_points(results_dir: Path) -> list[tuple[str, float, float]]:
    """All points from the JSONs under `results_dir` (one folder per bench); unreadable files are logged and skipped."""
    points: list[tuple[str, float, float]] = []
    for f in sorted(Path(results_dir).rglob("*.json")):
        try:
            points += find_bench_points(json.loads(f.read_text()), f.stem)
        except (OSError, ValueError) as e:
            log.warning("skipping bench results %s: %s", f, e)
    return points


class Charts(QWidget):
    """Two tabs: 'This render' (bar per window, coloured by level) and 'Speed vs accuracy'."""

    def __init__(self, results_dir: Path | None = None, parent=None) -> None:
        super().__init__(parent)
        pg.setConfigOptions(antialias=True)
        self.tabs = QTabWidget()
        self.window_plot = pg.PlotWidget(background=(30, 30, 34))
        self.window_plot.setLabel("bottom", "window (plan order)")
        self.window_plot.setLabel("left", "seconds")
        self.window_plot.setMinimumHeight(140)
        self.legend = QLabel()  # level colours, below the plot (an in-plot legend hides bars)
        self.legend.setWordWrap(True)
        self.legend.setStyleSheet("QLabel { background: #1e1e22; color: #e0e0e4; padding: 3px; }")
        self.legend.setTextFormat(Qt.TextFormat.RichText)
        self._legend_levels: set[int] = set()
        self.num_windows = 0
        self.bench_plot = pg.PlotWidget(background=(30, 30, 34))
        self.bench_plot.setLabel("bottom", "seconds per frame")
        self.bench_plot.setLabel("left", "PSNR (dB)")
        self.bench_note = QLabel()
        self.bench_note.setWordWrap(True)
        self.bench_note.setStyleSheet("QLabel { background: #1e1e22; color: #e0e0e4; padding: 3px; }")
        bench = QWidget()
        bl = QVBoxLayout(bench)
        bl.setContentsMargins(0, 0, 0, 0)
        bl.addWidget(self.bench_plot, 1)
        bl.addWidget(self.bench_note)
        this = QWidget()
        tl = QVBoxLayout(this)
        tl.setContentsMargins(0, 0, 0, 0)
        tl.addWidget(self.window_plot, 1)
        tl.addWidget(self.legend)
        self.tabs.addTab(this, "This render")
        self.tabs.addTab(bench, "Speed vs accuracy")
        lay = QVBoxLayout(self)
        lay.setContentsMargins(0, 0, 0, 0)
        lay.addWidget(self.tabs)
        self.windows: list[tuple[int, int, float]] = []  # (window index, level, seconds)
        self.top_level = 1
        self.reset(1)
        if results_dir is not None:
            self.load_bench(results_dir)

    # -- this render -----------------------------------------------------------
    def reset(self, top_level: int, num_windows: int = 0) -> None:
        self.windows.clear()
        self.top_level = top_level
        self.num_windows = num_windows
        self.window_plot.clear()
        self.window_plot.setLabel("bottom", "batch of frames" if top_level <= 0 else "window (plan order)")  # 0: a per-frame tier
        self._legend_levels.clear()
        self.legend.setText("Seconds per window of the current render appear here as windows finish.")
        if num_windows:
            self.window_plot.setXRange(-0.6, num_windows - 0.4, padding=0)

    def add_window(self, index: int, level: int, seconds: float) -> None:
        self.windows.append((index, level, seconds))
        c = level_colour(level, self.top_level)
        bar = pg.BarGraphItem(x=[index], height=[seconds], width=0.8, brush=c, pen=c.darker(150))
        self.window_plot.addItem(bar)
        if self.num_windows:
            self.window_plot.setXRange(-0.6, max(self.num_windows, index + 1) - 0.4, padding=0)
        if level not in self._legend_levels:
            if not self._legend_levels:
                self.legend.setText("")
            self._legend_levels.add(level)
            parts = []
            for lv in sorted(self._legend_levels, reverse=True):
                col = level_colour(lv, self.top_level).name()
                name = "frames (one pass each)" if lv <= 0 else "keyframes" if lv == self.top_level else f"level {lv}"
                parts.append(f"<span style='color:{col}'>&#9632;</span> {name}")
            self.legend.setText("&nbsp;&nbsp;".join(parts))

    # -- bench -----------------------------------------------------------------
    def load_bench(self, results_dir: Path) -> int:
        points = load_bench_points(results_dir) if Path(results_dir).is_dir() else []
        self.bench_plot.clear()
        if not points:
            self.bench_note.setText(f"No benchmark results yet ({results_dir}/*/*.json with seconds_per_frame and psnr).")
            return 0
        xs = [p[1] for p in points]
        ys = [p[2] for p in points]
        self.bench_plot.addItem(pg.ScatterPlotItem(x=xs, y=ys, size=10, brush=pg.mkBrush(64, 170, 255), pen=pg.mkPen("w")))
        below = labels_below(points, log_x=False)  # this plot's x axis is linear
        for i, (label, x, y) in enumerate(points):
            t = pg.TextItem(label, color=(230, 230, 230), anchor=(0, 0) if i in below else (0, 1))
            t.setPos(x, y)
            self.bench_plot.addItem(t)
        self.bench_note.setText(f"{len(points)} settings from {results_dir}")
        return len(points)
