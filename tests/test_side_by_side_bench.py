"""bench.side_by_side without Cycles: a tiny synthetic shot rendered by every tier through the Renderer (a fake model: no
weights), the picture and the JSON written with every panel's name, finite PSNRs and seconds per frame; and a PNG over
the size budget comes back as a palette PNG."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest
from test_tiers import with_net

from bench import side_by_side as S
from bench.stability_shots import SyntheticShot
from x2video.channels import tonemap
from x2video.io.shotdir import write_shot_folder
from x2video.metrics.image import psnr

pytest.importorskip("matplotlib")


def test_side_by_side_writes_the_picture_and_the_figures(tmp_path, monkeypatch):
    model = with_net()
    monkeypatch.setattr("x2video.weights.load_model", lambda *a, **k: model)
    shot_dir = tmp_path / "data" / "test" / "room"
    shot = SyntheticShot(3, (32, 48))
    write_shot_folder(shot, shot_dir)
    png, out = tmp_path / "docs" / "side_by_side.png", tmp_path / "side_by_side.json"
    assert S.main(["--shot", str(shot_dir), "--frame", "1", "--no-cycles", "--threads", "1", "--png", str(png), "--out", str(out)]) == 0
    res = json.loads(out.read_text())
    labels = [p["label"] for p in res["panels"]]
    assert labels[:3] == ["formula (albedo × irradiance)", "tier 1", "diffusion (fast preset)"] and labels[3].startswith(S.GROUND_TRUTH)
    for p in res["panels"][:3]:
        for k in ("psnr", "ssim", "psnr_shot", "seconds_per_frame", "cpu_seconds_per_frame"):
            assert isinstance(p[k], float) and math.isfinite(p[k]), (p["label"], k)
        assert p["caption"].endswith(" s/frame") and f"{p['psnr']:.2f} dB" in p["caption"]
    # the formula panel is albedo x irradiance scored against the shot's rgb; tier 1's net (random here) changes the frame
    want = psnr(tonemap(shot.channel("albedo", 1) * shot.channel("irradiance", 1)), tonemap(shot.channel("rgb", 1)))
    assert res["panels"][0]["psnr"] == pytest.approx(want, abs=0.05)
    assert res["panels"][1]["psnr"] != pytest.approx(res["panels"][0]["psnr"], abs=1e-3)
    assert res["panels"][2]["sampler"] == "ddim" and res["panels"][2]["steps"] == 4  # the fast preset without LCM weights
    assert res["panels"][3]["psnr"] is None
    assert res["frame"] == 1 and res["size"] == [48, 32] and res["cycles"] is None
    assert res["command"].startswith("python -m bench.side_by_side --shot ") and str(tmp_path) not in json.dumps(res)  # machine-independent
    assert "cpu" in res["machine"] and res["png"]["bytes"] == png.stat().st_size < S.PNG_BUDGET_BYTES
    from PIL import Image

    with Image.open(png) as im:
        assert im.size == tuple(res["png"]["size"]) and im.size[0] >= 4 * 48


def test_a_large_picture_becomes_a_palette_png(tmp_path, monkeypatch):
    monkeypatch.setattr(S, "PNG_BUDGET_BYTES", 1000)
    rng = np.random.default_rng(0)
    gt = rng.random((40, 60, 3)).astype(np.float32)
    panels = [S.scored(S.Panel("noisy", "noisy", np.clip(gt + 0.05, 0, 1), 0.5, 1.0), gt), S.Panel("gt", S.GROUND_TRUTH, gt, caption="truth")]
    res = S.write_outputs(panels, tmp_path / "p.png", tmp_path / "p.json", {"format": "test"}, footer="a footer")
    row = res["panels"][0]
    assert res["png"]["palette"] and math.isfinite(row["psnr"]) and row["caption"] == f"PSNR {row['psnr']:.2f} dB · 0.50 s/frame"
    from PIL import Image

    with Image.open(tmp_path / "p.png") as im:
        assert im.mode == "P"


def test_side_by_side_scores_against_a_truth_apart_and_names_it(tmp_path, monkeypatch):
    """A shot with SHOT/truth/ (`x2video dataset truth`): every panel is scored against it, not the shot's rgb, the
    ground-truth panel says its samples and seed, and a Cycles panel on the truth's own seed is refused."""
    from x2video.io.image import write_exr
    from x2video.io.truth import FORMAT, RECORD, TRUTH_DIR, truth_frame_path

    model = with_net()
    monkeypatch.setattr("x2video.weights.load_model", lambda *a, **k: model)
    shot_dir = tmp_path / "data" / "test" / "room"
    shot = SyntheticShot(3, (32, 48))
    write_shot_folder(shot, shot_dir)
    (shot_dir / TRUTH_DIR).mkdir()
    for t in range(3):
        rgb = 0.5 * shot.channel("rgb", t)
        write_exr(truth_frame_path(shot_dir, t), {c: rgb[..., i] for i, c in enumerate("RGB")}, "float")
    (shot_dir / TRUTH_DIR / RECORD).write_text(json.dumps({"format": FORMAT, "samples": 64, "seed": 7, "frames": 3, "complete": True,
                                                           "seconds": {"0": 2.0, "1": 4.0, "2": 3.0}}))
    out = tmp_path / "sbs.json"
    assert S.main(["--shot", str(shot_dir), "--frame", "1", "--no-cycles", "--threads", "1", "--png", str(tmp_path / "p.png"),
                   "--out", str(out)]) == 0
    res = json.loads(out.read_text())
    want = psnr(tonemap(shot.channel("albedo", 1) * shot.channel("irradiance", 1)), tonemap(0.5 * shot.channel("rgb", 1)))
    assert res["panels"][0]["psnr"] == pytest.approx(want, abs=0.05)
    assert res["truth"] == "apart, 64 spp seed 7"
    gt = res["panels"][3]
    assert gt["label"] == f"{S.GROUND_TRUTH}: Cycles 64 spp + OIDN" and gt["seconds_per_frame"] == pytest.approx(3.0)
    assert gt["caption"] == "3 s/frame · seed 7, apart from the passes"
    with pytest.raises(SystemExit, match="seed of the shot's truth apart"):
        S.main(["--shot", str(shot_dir), "--frame", "1", "--cycles-seed", "7", "--threads", "1", "--out", str(tmp_path / "x.json")])
