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


def test_base_fps_times_tier_1s_net_on_an_object_and_the_whole_frame() -> None:
    """--base-fps (issue 52): every tier-1 row ran the net (a roughness raised: a surface made glossier would keep the
    formula's difference and time nothing of tier 1), the tier-0 rows did not; wall and CPU seconds a frame."""
    import torch

    from bench.editor_latency_base import base_difference_fps

    threads = torch.get_num_threads()
    try:
        rows = base_difference_fps(repeats=1, size=(48, 64))
    finally:
        torch.set_num_threads(threads)
    assert {r["edit"] for r in rows if r["difference"].startswith("tier 1")} >= {"whole frame (worst case)", "small object (vase, 40x30)"}
    for r in rows:
        assert r["fps"] > 0 and r["cpu_s_per_frame"] >= 0
        assert (r["residual_calls"] > 0) == r["difference"].startswith("tier 1"), r
