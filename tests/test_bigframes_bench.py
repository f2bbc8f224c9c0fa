"""bench.bigframes at its cheapest: one small case per tier-1 mode, each in its own process as the bench runs them,
with the shipped weights; the table says where the net ran."""
from __future__ import annotations

from bench import bigframes


def test_bigframes_cases_report_where_tier_1_ran() -> None:
    size = (640, 448)  # 286,720 pixels: above the default residual_pixels (512 x 512), far below one tile
    work = bigframes.measure_case(size, "residual", 2, 1, timeout=300)
    full = bigframes.measure_case(size, "residual@full", 2, 1, timeout=300)
    for case in (work, full):
        assert "error" not in case, case
        assert case["size"] == list(size) and case["frames"] == 2 and case["sec_per_frame"] > 0 and case["peak_rss_gb"] > 0
        assert "tiles" not in case
    w, h = work["working_size"]
    assert (w, h) == (608, 424) and w * h <= 512 * 512  # the aspect kept, on the net's factor-8 grid
    assert full["working_size"] is None
    table = bigframes.markdown({"command": "test", "machine_note": "test", "cases": [work, full]})
    assert "network at 608×424" in table and "| 640×448 | residual@full |" in table
