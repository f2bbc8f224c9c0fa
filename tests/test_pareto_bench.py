"""bench.pareto on a one-shot data set: every row measured with finite numbers, the formula among them, what could not be
measured said, the summary and the Markdown written (a fake model: no weights); the Cycles rows on a tiny path-traced
room where bpy is installed (slow)."""
from __future__ import annotations

import json
import math
import subprocess
import sys

import numpy as np
import pytest
from test_tiers import with_net

from bench.pareto import methods as pareto_methods
from bench.pareto.chart import draw
from bench.pareto.cli import main
from bench.pareto.measure import NEAR_BEST_DB
from bench.pareto.merge import MergeError
from bench.pareto.methods import Method, parse_method, warm_up
from bench.stability_shots import SyntheticShot
from x2video.channels import tonemap
from x2video.io.paths import portable_path
from x2video.io.shotdir import write_shot_folder
from x2video.metrics.image import psnr


def fake_data(root, frames: int = 3):
    shot = SyntheticShot(frames, (32, 48))
    write_shot_folder(shot, root / "test" / "shot_000")
    return shot


def test_parse_method_and_round_trip_with_the_editor_key():
    from x2video.render.settings import RenderSettings
    from x2video_app._qt.charts import pareto_key

    assert parse_method("lcm-2-seq") == Method("lcm-2-seq", "diffusion", "lcm", 2, "sequential")
    assert parse_method("cycles-64").label == "Cycles 64 spp + OIDN"
    for key in ("formula", "residual", "ddim-20", "lcm-2-seq"):
        m = parse_method(key)
        tier = m.kind
        s = RenderSettings(sampler=m.sampler or "ddim", steps=m.steps or 20, scheme=m.scheme)
        assert pareto_key(tier, s) == key
    with pytest.raises(ValueError, match="unknown method"):
        parse_method("euler-3")


def test_pareto_rows_summary_and_markdown(tmp_path, monkeypatch):
    model = with_net()
    model.has_lcm = True
    monkeypatch.setattr("x2video.weights.load_model", lambda *a, **k: model)
    shot = fake_data(tmp_path / "data")
    out = tmp_path / "pareto.json"
    methods = "formula,residual,ddim-1,ddim-2,lcm-1,ddim-1-seq,cycles-4"
    assert main(["--data", str(tmp_path / "data"), "--sizes", "48x32", "--rooms", "1", "--frames", "3", "--methods", methods,
                   "--reference-samples", "0", "--threads", "1", "--out", str(out), "--no-png"]) == 0
    res = json.loads(out.read_text())
    rows = {r["method"]: r for r in res["rows"]}
    assert set(rows) == {"formula", "residual", "ddim-1", "ddim-2", "lcm-1"}
    for r in rows.values():
        assert r["size"] == [48, 32] and r["frames"] == 3
        for k in ("psnr", "ssim", "tc", "psnr_dataset", "seconds_per_frame", "cpu_seconds_per_frame", "wall_seconds_per_frame"):
            assert isinstance(r[k], float) and math.isfinite(r[k]), (r["method"], k)
        assert r["seconds_per_frame"] == r["cpu_seconds_per_frame"] > 0  # the default clock
    # the formula row is albedo x irradiance scored against the shot's rgb (no bench reference here)
    want = np.mean([psnr(tonemap(shot.channel("albedo", t) * shot.channel("irradiance", t)), tonemap(shot.channel("rgb", t))) for t in range(3)])
    assert rows["formula"]["psnr"] == pytest.approx(want, abs=0.05)
    assert rows["formula"]["psnr"] == pytest.approx(rows["formula"]["psnr_dataset"])
    assert rows["residual"]["psnr"] != pytest.approx(rows["formula"]["psnr"], abs=1e-3)  # the net changed the frames
    skipped = {u["method"]: u["reason"] for u in res["unavailable"]}
    assert "same windows" in skipped["ddim-1-seq"] and "not a procedural Cycles room" in skipped["cycles-4"]
    assert res["ground_truth"]["48x32"]["kind"] == "data set frames"
    s = res["summary"]["48x32"]
    assert s["fastest_near_best"] in {r["label"] for r in rows.values()} and s["speedup_over_ddim20_cpu"] is None and s["speedup_over_cycles64_wall"] is None
    assert s["fastest_psnr"] >= s["best_psnr"] - NEAR_BEST_DB
    md = out.with_suffix(".md").read_text()
    assert "formula (tier 0)" in md and "Ground truth at 48x32" in md
    pytest.importorskip("matplotlib")
    png = draw(res, tmp_path / "pareto.png")
    assert png.stat().st_size > 10_000


def test_missing_size_names_what_is_there(tmp_path):
    fake_data(tmp_path / "data", 2)
    with pytest.raises(SystemExit, match="no finished shot of 160x112.*48x32 \\(1\\)"):
        main(["--data", str(tmp_path / "data"), "--sizes", "160x112", "--methods", "formula", "--reference-samples", "0",
                "--out", str(tmp_path / "p.json")])


bpy_missing = subprocess.run([sys.executable, "-c", "import importlib.util,sys; sys.exit(importlib.util.find_spec('bpy') is None)"]).returncode


@pytest.mark.slow
@pytest.mark.skipif(bool(bpy_missing), reason="bpy is not installed: `pip install -e '.[cycles]'` (scripts/setup.sh does)")
def test_cycles_rows_rebuild_the_same_room(tmp_path):
    data = tmp_path / "pt"
    cmd = [sys.executable, "-m", "x2video", "dataset", "make", "--renderer", "cycles", "--rooms", "1", "--frames", "2", "--size", "48x32",
           "--samples", "4", "--workers", "1", "--test-every", "1", "--seed", "3", "--splits", "test", "--out", str(data)]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    out = tmp_path / "p.json"
    assert main(["--data", str(data), "--sizes", "48x32", "--rooms", "1", "--frames", "2", "--methods", "formula,cycles-1,cycles-4",
                   "--reference-samples", "16", "--threads", "1", "--out", str(out), "--no-png"]) == 0
    res = json.loads(out.read_text())
    rows = {r["method"]: r for r in res["rows"]}
    assert set(rows) == {"formula", "cycles-1", "cycles-4"} and not res["unavailable"]
    assert res["ground_truth"]["48x32"]["kind"] == "bench reference" and res["ground_truth"]["48x32"]["samples"] == 16
    for r in rows.values():
        assert all(math.isfinite(r[k]) for k in ("psnr", "tc", "psnr_dataset", "seconds_per_frame"))
    # 4 samples with the data set's seed rebuild its frames (same room, cameras, light gain): identical up to half floats
    assert rows["cycles-4"]["psnr_dataset"] > 50
    assert rows["cycles-4"]["psnr"] > rows["cycles-1"]["psnr"] - 1.0


# --------------------------------------------------------------------------------------------- --merge
class DimmerShot(SyntheticShot):
    """The same shot names and size with other frames (a data set rebuilt under the same names)."""

    def _read(self, name, t):
        a = super()._read(name, t)
        return a * 0.9 if name == "albedo" else a


def _run(data, out, methods, frames="3", *extra):
    return main(["--data", str(data), "--sizes", "48x32", "--rooms", "1", "--frames", frames, "--methods", methods,
                   "--reference-samples", "0", "--threads", "1", "--out", str(out), "--no-png", *extra])


def test_merge_replaces_the_rerun_rows_keeps_the_others_and_names_their_runs(tmp_path, monkeypatch):
    monkeypatch.setattr("x2video.weights.load_model", lambda *a, **k: with_net(0))
    fake_data(tmp_path / "data")
    old, merged = tmp_path / "pareto.json", tmp_path / "merged.json"
    assert _run(tmp_path / "data", old, "formula,residual,ddim-1") == 0
    before = {r["method"]: r for r in json.loads(old.read_text())["rows"]}
    monkeypatch.setattr("x2video.weights.load_model", lambda *a, **k: with_net(1))  # retrained tier-1 weights
    assert _run(tmp_path / "data", merged, "residual", "3", "--merge", str(old)) == 0
    res = json.loads(merged.read_text())
    rows = {r["method"]: r for r in res["rows"]}
    assert [r["method"] for r in res["rows"]] == ["formula", "residual", "ddim-1"]  # formula measured again first, as a check
    assert [r["id"] for r in res["runs"]] == [1, 2] and res["runs"][1]["methods"] == ["formula", "residual"]
    assert rows["ddim-1"]["run"] == 1 and rows["ddim-1"]["psnr"] == before["ddim-1"]["psnr"]  # kept as it was
    assert rows["residual"]["run"] == rows["formula"]["run"] == 2
    assert rows["residual"]["psnr"] != pytest.approx(before["residual"]["psnr"], abs=1e-4)  # the other net's row
    assert rows["formula"]["psnr"] == pytest.approx(before["formula"]["psnr"], abs=1e-6)
    run2 = res["runs"][1]
    assert "--merge" in run2["command"] and run2["date"] and run2["load_average_start"] and "merge_checks" in run2
    assert "digests equal" in run2["merge_checks"]["48x32"]
    assert res["summary"]["48x32"]["best_psnr"] == max(r["psnr"] for r in res["rows"])
    md = merged.with_suffix(".md").read_text()
    assert "2 runs" in md and "| run |" in md
    from x2video_app._qt.charts import load_pareto  # the editor reads the merged result as before

    assert [r["method"] for r in load_pareto(merged)["rows"]] == ["formula", "residual", "ddim-1"]


def test_merge_refuses_other_frames_other_data_and_another_reference(tmp_path, monkeypatch):
    monkeypatch.setattr("x2video.weights.load_model", lambda *a, **k: with_net(0))
    fake_data(tmp_path / "data")
    old = tmp_path / "pareto.json"
    assert _run(tmp_path / "data", old, "formula,residual") == 0
    kept = old.read_text()
    with pytest.raises(MergeError, match=r"frames \[2\].*\[3\]"):
        _run(tmp_path / "data", tmp_path / "m.json", "residual", "2", "--merge", str(old))
    write_shot_folder(DimmerShot(3, (32, 48)), tmp_path / "data" / "test" / "shot_000", overwrite=True)
    with pytest.raises(MergeError, match="data set was rebuilt"):
        _run(tmp_path / "data", tmp_path / "m.json", "residual", "3", "--merge", str(old))
    assert old.read_text() == kept and not (tmp_path / "m.json").exists()  # refused before anything was written
    # a result from before digests were recorded: the re-scored formula row is the check, and it catches the other frames
    legacy = json.loads(kept)
    for g in legacy["ground_truth"].values():
        for k in ("shots", "frames", "data_sha256", "reference_sha256"):
            g.pop(k)
    (tmp_path / "legacy.json").write_text(json.dumps(legacy))
    with pytest.raises(MergeError, match="formula row re-scored.*differs"):
        _run(tmp_path / "data", tmp_path / "m.json", "residual", "3", "--merge", str(tmp_path / "legacy.json"))
    fake_data(tmp_path / "data2")  # the original frames again (another folder, same name as recorded)
    legacy["data"] = [portable_path(tmp_path / "data2")]  # as the bench records it
    (tmp_path / "legacy.json").write_text(json.dumps(legacy))
    assert _run(tmp_path / "data2", tmp_path / "m.json", "residual", "3", "--merge", str(tmp_path / "legacy.json")) == 0
    res = json.loads((tmp_path / "m.json").read_text())
    assert "formula row re-scored" in res["runs"][1]["merge_checks"]["48x32"]
    assert res["runs"][0]["command"] == legacy["command"] and res["runs"][0]["commit"] == legacy["machine"]["git_commit"]


def test_a_section_of_its_own_compares_the_schemes_and_leaves_the_main_rows(tmp_path, monkeypatch):
    monkeypatch.setattr("x2video.weights.load_model", lambda *a, **k: with_net(0))
    fake_data(tmp_path / "data", frames=7)  # longer than a window of 5: sequential runs other windows
    old = tmp_path / "pareto.json"
    assert _run(tmp_path / "data", old, "formula,residual") == 0
    long = tmp_path / "long.json"
    assert _run(tmp_path / "data", long, "ddim-1,ddim-1-seq", "7") == 0  # measured alone, merged after (--from-result)
    assert main(["--merge", str(old), "--section", "long shot", "--from-result", str(long), "--out", str(tmp_path / "m.json"), "--no-png"]) == 0
    res = json.loads((tmp_path / "m.json").read_text())
    assert [r["method"] for r in res["rows"]] == ["formula", "residual"] and all(r["run"] == 1 for r in res["rows"])
    assert "--from-result" in res["runs"][1]["merged_with"] == res["command"] and "--out" in res["runs"][1]["command"]
    sec = res["sections"]["long shot"]
    assert {r["method"] for r in sec["rows"]} == {"ddim-1", "ddim-1-seq"} and sec["ground_truth"]["48x32"]["frames"] == [7]
    (c,) = sec["schemes"]
    assert c["setting"] == "ddim-1" and c["psnr_recursive"] != c["psnr_sequential"]
    assert "## long shot" in (tmp_path / "m.md").read_text()
    with pytest.raises(SystemExit, match="go with --merge"):
        main(["--section", "x", "--data", str(tmp_path / "data")])
    pytest.importorskip("matplotlib")
    assert draw(res, tmp_path / "m.png").stat().st_size > 10_000


def test_warm_up_renders_the_frames_and_schemes_the_rows_render(monkeypatch):
    """The engine exports a graph per window size and kind: a warm-up of other frames leaves that to the first row."""
    seen = []
    monkeypatch.setattr(pareto_methods, "render_timed", lambda r, shot, s: seen.append((shot, s.quality, s.sampler, s.scheme, s.steps, s.frames)))
    a, b = object(), object()
    warm_up(with_net(), [a, b], [8, 8], [parse_method(k) for k in ("formula", "residual", "lcm-2", "lcm-2-seq", "ddim-4", "ddim-20")])
    assert sorted(seen, key=str) == sorted([(a, "residual", "ddim", "recursive", 20, (0, 8)), (a, "diffusion", "lcm", "recursive", 1, (0, 8)),
                                            (a, "diffusion", "lcm", "sequential", 1, (0, 8)), (a, "diffusion", "ddim", "recursive", 1, (0, 8))], key=str)
