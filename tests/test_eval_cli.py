"""`x2video eval` end to end on a tiny procedural room with untrained tiny models: every table and row, finite
values, the classical baseline on every row, the Markdown; the LCM/FID path; clear failures for missing weights."""
from __future__ import annotations

import copy
import json
import math
from pathlib import Path

import pytest
from eval_fixtures import make_dataset, one_thread  # noqa: F401  (fixture)

from x2video.cli import main


@pytest.fixture(scope="module")
def data(tmp_path_factory) -> Path:
    return make_dataset(tmp_path_factory.mktemp("evaldata"), frames=9)


def _finite(v) -> bool:
    return isinstance(v, (int, float)) and math.isfinite(v)


def test_eval_cli_untrained_all_tables(data, tmp_path, one_thread, capsys):
    out = tmp_path / "res"
    rc = main(["eval", "--untrained", "--data", str(data), "--frames", "3", "--long-frames", "6", "--steps", "1",
               "--long-conditions", "full,drop_irradiance+ref", "--no-fid", "--threads", "1", "--renders", "1", "--out", str(out)])
    assert rc == 0, capsys.readouterr().err
    res = json.loads((out / "results.json").read_text())
    assert res["format"] == "x2video-eval" and set(res["tables"]) == {"a", "b", "c", "d"}
    labels = {k: [r["label"] for r in t["rows"]] for k, t in res["tables"].items()}
    assert labels["a"] == ["Image model (per frame)", "Video model"]
    assert labels["b"] == [f"{k}{x}" for k in ("Full channels", "Mask A|M|R", "Drop irradiance") for x in ("", " + Text", " + Ref.")]
    assert labels["c"] == ["Sequential", "Recursive", "Sequential, Drop irradiance + Ref.", "Recursive, Drop irradiance + Ref."]
    assert labels["d"] == ["DDIM-1", "DDIM-1 + Ref.", "LCM-2", "LCM-2 + Ref."]
    for key, table in res["tables"].items():
        for row in table["rows"]:
            if row["label"].startswith("LCM"):
                assert row["available"] is False and "LCM weights" in row["reason"]
                continue
            assert row["available"], row
            for side in ("model", "baseline"):
                for m in ("psnr", "ssim", "tc", "seconds_per_frame"):
                    assert _finite(row[side][m]), (key, row["label"], side, m, row[side][m])
            assert row["model"]["frames"] == (6 if key == "c" else 3)
    rows = {(k, r["label"]): r for k, t in res["tables"].items() for r in t["rows"]}
    # repeated settings are rendered once and say so
    assert rows[("b", "Full channels")]["same_render_as"] == "a: Video model"
    assert rows[("d", "DDIM-1 + Ref.")]["same_render_as"] == "b: Full channels + Ref."
    # the baseline follows the edited channels: black without irradiance, holes where A|M|R is masked
    full_b = rows[("b", "Full channels")]["baseline"]["psnr"]
    assert rows[("b", "Drop irradiance")]["baseline"]["psnr"] < full_b
    assert rows[("b", "Mask A|M|R")]["baseline"]["psnr"] < full_b
    assert rows[("b", "Mask A|M|R + Text")]["inputs"]["room_00001"]["local_prompts"]
    # the text reaches the model (an untrained model ignores the reference: zero-initialised inputs, alphas 0)
    assert rows[("b", "Full channels + Text")]["model"]["ssim"] != rows[("b", "Full channels")]["model"]["ssim"]
    assert rows[("c", "Sequential")]["model"]["psnr"] != rows[("c", "Recursive")]["model"]["psnr"]
    # table (c) under a condition: the baseline without irradiance is black, the model still renders
    rec_drop = rows[("c", "Recursive, Drop irradiance + Ref.")]
    assert rec_drop["condition"] == {"kind": "drop_irradiance", "text": False, "reference": True}
    assert rec_drop["baseline"]["psnr"] < rows[("c", "Recursive")]["baseline"]["psnr"]
    assert rec_drop["model"]["psnr"] != rows[("c", "Recursive")]["model"]["psnr"]
    assert res["unavailable"]["fvd"]["reason"] and res["unavailable"]["lpips"]["reason"]
    assert res["machine"]["cpu_cores"] and res["wall_seconds"] > 0
    assert res["command"].startswith("x2video eval --untrained --data")
    assert "--long-conditions full,drop_irradiance+ref --tables a,b,c,d" in res["command"]  # table (c) reproduces
    assert res["data"]["main"]["size"] == [64, 48]
    md = (out / "results.md").read_text()
    for head in ("### (a)", "### (b)", "### (c)", "### (d)"):
        assert head in md
    assert "| Mask A\\|M\\|R + Text |" in md and "n/a¹" in md and "LPIPS not computed" in md
    assert "n/a: no LCM weights" in md and "classical PSNR" in md and "Reproduce: `x2video eval" in md
    assert (out / "renders" / "room_00001.png").stat().st_size > 0 and (out / "renders" / "room_00001.mp4").stat().st_size > 0


def test_eval_reference_lcm_and_fid(data, one_thread):
    """Library path: LCM rows run when distilled weights exist, FID is finite, and the reference reaches the model."""
    import torch

    from x2video.eval.config import EvalConfig
    from x2video.eval.data import load_eval_shots
    from x2video.eval.runner import EvalModels, evaluate
    from x2video.model.pipeline import X2VideoModel

    base = X2VideoModel.untrained("tiny")
    with torch.no_grad():  # make the reference input channels live (untrained conversion zero-initialises them)
        base.unet.conv_in.weight[:, 23:27] = 0.2 * torch.randn_like(base.unet.conv_in.weight[:, 23:27])
    lcm = X2VideoModel(base.config, base.unet, base.vae, base.text_encoder, copy.deepcopy(base.unet), untrained=True)
    shots = load_eval_shots(data, frames=3)
    res = evaluate(EvalModels(lcm), {"main": shots}, EvalConfig(tables=("d",), frames=3, steps=1, fid=True))
    rows = {r["label"]: r for r in res["tables"]["d"]["rows"]}
    assert all(r["available"] for r in rows.values())
    assert rows["LCM-2"]["settings"]["sampler"] == "lcm"
    assert _finite(rows["LCM-2"]["model"]["fid"]) and _finite(rows["DDIM-1"]["baseline"]["fid"])
    assert rows["DDIM-1 + Ref."]["model"]["psnr"] != rows["DDIM-1"]["model"]["psnr"]
    assert rows["DDIM-1 + Ref."]["inputs"]["room_00001"]["reference"].startswith("ground-truth")


def test_eval_fails_clearly_without_weights(data, tmp_path, capsys, monkeypatch):
    out = tmp_path / "res"
    rc = main(["eval", "--weights", str(tmp_path / "nope"), "--data", str(data), "--out", str(out)])
    assert rc == 2 and "nope does not exist" in capsys.readouterr().err
    empty = tmp_path / "empty"
    empty.mkdir()
    rc = main(["eval", "--weights", str(empty), "--data", str(data), "--out", str(out)])
    assert rc == 2 and "neither a model folder" in capsys.readouterr().err
    import x2video.weights

    monkeypatch.setattr(x2video.weights, "shipped_weights", lambda *a, **k: None)
    rc = main(["eval", "--data", str(data), "--out", str(out)])
    err = capsys.readouterr().err
    assert rc == 2 and "no --weights given" in err and "--untrained" in err
    rc = main(["eval", "--untrained", "--data", str(tmp_path / "nodata"), "--out", str(out)])
    assert rc == 2 and "nodata does not exist" in capsys.readouterr().err
    assert not (out / "results.json").exists()


def test_eval_rejects_an_image_model_as_video_weights(data, tmp_path, capsys, one_thread):
    from x2video.model.pipeline import X2VideoModel

    X2VideoModel.untrained("tiny", video=False).save_pretrained(tmp_path / "img")
    rc = main(["eval", "--weights", str(tmp_path / "img"), "--data", str(data), "--out", str(tmp_path / "r")])
    assert rc == 2 and "holds an image model" in capsys.readouterr().err
