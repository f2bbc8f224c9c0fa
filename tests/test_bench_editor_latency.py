"""bench.editor_latency end to end at its cheapest (untrained tiny model, the formula tier, one press, offscreen), in a
fresh interpreter as the bench is run: the editor starts on the demo, Render puts frames on screen, and the result
records the latencies, the thread counts and the GUI's tick gaps during the render."""
from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

pytest.importorskip("PySide6")


def test_editor_latency_bench_measures_a_render(tmp_path) -> None:
    out = tmp_path / "latency.json"
    env = {**os.environ, "QT_QPA_PLATFORM": "offscreen", "XDG_CACHE_HOME": os.environ.get("XDG_CACHE_HOME", str(tmp_path / "xdg"))}
    subprocess.run([sys.executable, "-m", "bench.editor_latency", "--untrained", "--quality", "formula", "--renders", "1", "--full",
                    "--drag", "formula", "--drag-seconds", "0.5", "--out", str(out)], check=True, env=env, timeout=600, capture_output=True)
    result = json.loads(out.read_text())
    summary = result["summary (first press; from process start, or from the click)"]
    assert 0 < summary["startup_to_demo_visible_s"] < summary["model_ready_s"]
    (press,) = result["renders"]
    assert press["status"] == "finished" and press["tier"] == "formula" and press["frames"] == result["shot"]["frames"] > 1
    assert 0 < press["press_to_frame_on_screen_s"] <= press["render_s"] + 1
    gaps = press["gui_tick_gap_ms"]
    assert gaps["ticks"] > 1 and 0 < gaps["median"] <= gaps["p95"] <= gaps["max"]
    assert press["threads"]["torch"] >= 1
    (drag,) = result["drags"]  # issue 43's slider drag: the live preview kept up, latest-wins, and settled on the last value
    assert drag["preview_tier"] == "formula" and drag["inputs"] == 30 and drag["stale_runs"] == 0  # (a starved machine may show none mid-drag)
    assert drag["requests"] == drag["frames_rendered"] + drag["dropped"] and drag["last_input_to_frame_s"] is not None
    assert drag["gui_tick_gap_ms"]["ticks"] > 1 and drag["settled_to_full_quality_s"] >= drag["last_input_to_frame_s"]
