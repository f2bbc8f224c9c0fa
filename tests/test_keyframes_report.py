"""bench.keyframes_report: the tables come from the JSON, with the cost formula and Cycles' curve read as documented."""
import math

from bench.keyframes_report import cycles_at, cycles_curve, render


def doc():
    rows = [{"clip": "room_1", "every": n, "method": m, "psnr": p, "psnr_min": p - 1, "ssim": 0.9, "tc": 1.0, "fill_seconds": 0.2}
            for n, m, p in [(8, "rife", 30.0), (8, "classical", 38.0)]]
    return {"command": "python -m bench.keyframes", "size": "32x24",
            "gbuffer_cost": {"headline": {"cpu_seconds_per_frame": 0.5, "wall_seconds_per_frame": 1.0}},
            "clips": [{"rows": rows, "frames": 17, "truth": {"samples": 32},
                       "cycles": [{"samples": 1, "cpu_seconds_per_frame": 2.0, "psnr": 30.0},
                                  {"samples": 4, "cpu_seconds_per_frame": 8.0, "psnr": 36.0}],
                       "keyframes": {"samples": 16, "cpu_seconds_per_frame": 16.0, "psnr_vs_truth": 42.0, "tc": 1.05}}]}


def test_curve_and_interpolation_in_log_time():
    curve = cycles_curve(doc())
    assert [round(s, 3) for s, _, _ in curve] == [2.0, 8.0, 16.0]
    assert cycles_at(curve, 4.0) == 33.0  # halfway in log time between 2 s (30 dB) and 8 s (36 dB)
    assert cycles_at(curve, 1.0) is None and cycles_at(curve, 20.0) is None


def test_table_cost_is_keyframe_over_n_plus_gbuffer_and_fill():
    text = render(doc())
    cost = 16.0 / 8 + (0.5 + 0.2) * 7 / 8
    line = next(ln for ln in text.splitlines() if ln.startswith("| 8 | classical"))
    cells = [c.strip() for c in line.strip("|").split("|")]
    assert cells[2] == "38.00" and cells[6] == f"{cost:.2f}"
    want = 30.0 + 6.0 * (math.log(cost) - math.log(2.0)) / (math.log(8.0) - math.log(2.0))
    assert cells[7] == f"{want:.2f}"
    assert "TC 1.050" in text


def test_other_sizes_get_their_own_result_and_gbuffer_cost_files_and_test_runs_refuse_the_validation_clip():
    import pytest

    from bench import keyframes as K

    assert K.result_name(False, "320x224") == "keyframes" and K.result_name(True, "320x224") == "keyframes_validation"
    assert K.result_name(False, "960x540") == "keyframes_960x540"
    assert K.gbuffer_cost_path("320x224") == K.GBUFFER_COST
    assert K.gbuffer_cost_path("960x540").name == "gbuffer_cost_960x540.json"
    with pytest.raises(SystemExit, match="not a test clip"):
        K.main(["--seeds", K.VALIDATION_SEEDS, "--clips", "/nonexistent"])
