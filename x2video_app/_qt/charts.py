"""pyqtgraph charts: seconds per window of the current render (by level), and speed vs accuracy: the chart of
`bench.pareto` (docs/pareto.json) with the current render's setting marked, else every bench result's points."""
from __future__ import annotations

import json
import logging
import math
from pathlib import Path
from typing import Any

import pyqtgraph as pg
from PySide6.QtCore import Qt
from PySide6.QtWidgets import QLabel, QTabWidget, QVBoxLayout, QWidget

from x2video.eval.report import labels_below
from x2video_app._qt.timeline import level_colour

log = logging.getLogger(__name__)

_SPEED_KEYS = ("seconds_per_frame", "sec_per_frame", "s_per_frame", "spf")
_ACC_KEYS = ("psnr", "PSNR")
_LABEL_KEYS = ("name", "label", "preset", "setting", "config")
#: where `bench.pareto` writes its chart's numbers (a source checkout), and a copy packaged with the weights
PARETO_PATHS = (Path(__file__).resolve().parents[2] / "docs" / "pareto.json", Path(__file__).resolve().parents[2] / "resources" / "pareto.json")
#: pareto family -> point colour
_FAMILY_COLOURS = {"formula": (200, 200, 200), "residual": (80, 200, 90), "ddim-recursive": (64, 150, 255), "ddim-sequential": (90, 210, 230),
                   "lcm-recursive": (255, 160, 40), "lcm-sequential": (240, 210, 60), "cycles": (230, 70, 70)}


def pareto_key(tier: str, settings: Any) -> str:
    """The `bench.pareto` method of a render: 'formula', 'residual', or 'ddim-S' / 'lcm-S' (with '-seq' for sequential
    sampling) from the RenderSettings the sampler ran with (a preset already resolved to sampler and steps)."""
    from x2video.tiers import registry  # importing it registers the built-in tiers

    if tier in registry.qualities() and tier != "auto" and not registry.windowed(tier):  # a per-frame tier is its own method
        return tier
    return f"{settings.sampler}-{settings.steps}" + ("-seq" if settings.scheme == "sequential" else "")


def pareto_path() -> Path | None:
    """The first of PARETO_PATHS that exists."""
    return next((p for p in PARETO_PATHS if p.is_file()), None)


def load_pareto(path: Path | None = None) -> dict | None:
    """docs/pareto.json (or `path`), or None when there is none or it cannot be read (logged)."""
    for p in [path] if path is not None else PARETO_PATHS:
        if p is not None and Path(p).is_file():
            try:
                data = json.loads(Path(p).read_text())
                if data.get("format") == "x2video-pareto" and isinstance(data.get("rows"), list):
                    data["_path"] = str(p)
                    return data
                log.warning("%s: not a bench.pareto result (format %r)", p, data.get("format"))
            except (OSError, ValueError) as e:
                log.warning("skipping %s: %s", p, e)
    return None


def section_row(data: dict, key: str, size: tuple[int, int]) -> tuple[str, dict] | None:
    """(section name, row) of method `key` at `size` among the sections of a bench.pareto result (`--section`: rows
    of other shots, e.g. recursive against sequential sampling on a shot longer than a window), or None."""
    for name, sec in (data.get("sections") or {}).items():
        for r in sec.get("rows") or []:
            if r.get("method") == key and tuple(r.get("size", ())) == tuple(size) and r.get("psnr") is not None:
                return name, r
    return None


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

    def __init__(self, results_dir: Path | None = None, parent=None, pareto: Path | None = None) -> None:
        """`pareto`: a bench.pareto JSON to chart (`pareto_path()`); without one, the points of every JSON under `results_dir`."""
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
        self._bars: list[pg.BarGraphItem] = []  # the plot's bar of each entry of `windows`
        self.top_level = 1
        self.reset(1)
        self.pareto = load_pareto(pareto) if pareto is not None else None
        self.marked: dict | None = None  # the pareto row of the current render's setting
        if self.pareto is not None:
            self.show_pareto()
        elif results_dir is not None:
            self.load_bench(results_dir)

    # -- this render -----------------------------------------------------------
    def reset(self, top_level: int, num_windows: int = 0) -> None:
        self.windows.clear()
        self._bars.clear()
        self.top_level = top_level
        self.num_windows = num_windows
        self.window_plot.clear()
        self.window_plot.setLabel("bottom", "batch of frames" if top_level <= 0 else "window (plan order)")  # 0: a per-frame tier
        self._legend_levels.clear()
        self.legend.setText("Seconds per window of the current render appear here as windows finish.")
        if num_windows:
            self.window_plot.setXRange(-0.6, num_windows - 0.4, padding=0)

    def add_window(self, index: int, level: int, seconds: float) -> None:
        """One bar per window; a window that delivers its frames in parts (the first keyframe alone) updates its
        bar to the window's time so far."""
        c = level_colour(level, self.top_level)
        bar = pg.BarGraphItem(x=[index], height=[seconds], width=0.8, brush=c, pen=c.darker(150))
        if self.windows and self.windows[-1][0] == index:
            self.windows[-1] = (index, level, seconds)
            self.window_plot.removeItem(self._bars.pop())
        else:
            self.windows.append((index, level, seconds))
        self._bars.append(bar)
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
    def show_pareto(self, key: str | None = None, size: tuple[int, int] | None = None) -> dict | None:
        """Plot docs/pareto.json's rows of the size nearest `size` (W, H; default the first), seconds per frame on a log
        axis against PSNR, and ring the row of method `key` (`pareto_key`). Returns that row, or None."""
        data = self.pareto or {}
        rows = [r for r in data.get("rows", []) if r.get("psnr") is not None and (r.get("seconds_per_frame") or 0) > 0]
        self.bench_plot.clear()
        self.marked = None
        if not rows:
            self.bench_note.setText("No speed/accuracy chart yet (python -m bench.pareto writes docs/pareto.json).")
            return None
        sizes = sorted({tuple(r["size"]) for r in rows})
        want = size or sizes[0]
        at = min(sizes, key=lambda s: abs(math.log(s[0] * s[1] / max(want[0] * want[1], 1))))
        rows = [r for r in rows if tuple(r["size"]) == at]
        self.bench_plot.setLogMode(x=True, y=False)
        self.bench_plot.setLabel("bottom", "seconds per frame (log)")
        for fam in dict.fromkeys(r.get("family", "") for r in rows):
            pts = sorted((r for r in rows if r.get("family", "") == fam), key=lambda r: r["seconds_per_frame"])
            c = _FAMILY_COLOURS.get(fam, (64, 170, 255))
            self.bench_plot.plot([r["seconds_per_frame"] for r in pts], [r["psnr"] for r in pts], pen=pg.mkPen(c, width=1),
                                 symbol="o", symbolBrush=pg.mkBrush(*c), symbolPen=pg.mkPen("w"), symbolSize=8)
            for r in pts:
                t = pg.TextItem(str(r.get("label", r.get("method"))).replace(" + OIDN", ""), color=c, anchor=(0, 1))
                t.setPos(math.log10(r["seconds_per_frame"]), r["psnr"])
                self.bench_plot.addItem(t)
        mark = next((r for r in rows if key is not None and r.get("method") == key), None)
        where = f"{at[0]}x{at[1]}, {data.get('_path', 'docs/pareto.json')}"
        if mark is not None:
            self.bench_plot.addItem(pg.ScatterPlotItem(x=[math.log10(mark["seconds_per_frame"])], y=[mark["psnr"]], size=22, symbol="o",
                                                       brush=pg.mkBrush(0, 0, 0, 0), pen=pg.mkPen((255, 255, 0), width=3)))
            self.marked = mark
            self.bench_note.setText(f"This render: {mark['label']}, measured {mark['seconds_per_frame']:.3g} s/frame and "
                                    f"{mark['psnr']:.2f} dB PSNR on path-traced rooms at {where}.")
        elif key is not None:
            other = section_row(data, key, at)
            if other is not None:  # e.g. sequential sampling, measured on a longer shot in a section of its own
                name, r = other
                self.bench_note.setText(f"This render ({r['label']}) is charted in section '{name}' of {data.get('_path', 'docs/pareto.json')} "
                                        f"(another shot): {r['seconds_per_frame']:.3g} s/frame, {r['psnr']:.2f} dB PSNR at {at[0]}x{at[1]}.")
            else:
                self.bench_note.setText(f"This render ({key}) is not among the measured settings ({where}).")
        else:
            self.bench_note.setText(f"{len(rows)} settings measured on path-traced rooms at {where}.")
        return mark

    def mark_setting(self, key: str, size: tuple[int, int] | None = None) -> dict | None:
        """Ring the current render's setting (`pareto_key`) on the speed/accuracy chart, at the size nearest `size` (W, H)."""
        return self.show_pareto(key, size) if self.pareto is not None else None

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
