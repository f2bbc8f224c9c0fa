"""Parts of `x2video.eval`: resizing for the model's size, control conditions, training size lookup, orderings,
Markdown, the model card from results + run folders, contact sheets, and the speed/accuracy chart."""
from __future__ import annotations

import importlib
import json
import math
from pathlib import Path

import numpy as np
import pytest
from train_fixtures import tiny_room

from x2video.eval.checks import orderings, orderings_markdown
from x2video.eval.conditions import Condition, build_edits, pick_objects
from x2video.eval.data import EvalView, resize_motion, training_size
from x2video.eval.report import results_markdown, row_line


def test_resize_motion_scales_vectors_and_keeps_occlusion():
    m = np.zeros((1, 8, 8, 2), np.float32)
    m[..., 0], m[..., 1] = 4.0, -2.0
    m[0, 0, 0] = np.nan  # occluded pixel in the top-left 2x2 block
    r = resize_motion(m, (4, 4))
    assert r.shape == (1, 4, 4, 2)
    assert np.isnan(r[0, 0, 0]).all()
    np.testing.assert_allclose(r[0, 1:, 1:], np.broadcast_to([2.0, -1.0], (3, 3, 2)), atol=1e-6)


def test_eval_view_cuts_frames_and_area_downsamples():
    shot = tiny_room(0, frames=6, size=(32, 24))
    v = EvalView(shot, frames=4, size=(16, 12))
    assert v.num_frames == 4 and v.size == (12, 16)
    rgb = v.channel("rgb", 1)
    np.testing.assert_allclose(rgb, shot.channel("rgb", 1).reshape(12, 2, 16, 2, 3).mean(axis=(1, 3)), atol=1e-5)
    ids = v.channel("ids", 1)
    assert ids.dtype == np.int32 and set(np.unique(ids)) <= set(np.unique(shot.channel("ids", 1)))
    assert v.info.object_captions == shot.info.object_captions


def test_training_size_from_run_state_and_training_json(tmp_path):
    cache = tmp_path / "cache"
    cache.mkdir()
    (cache / "meta.json").write_text(json.dumps({"size": [160, 112]}))
    model = tmp_path / "run" / "step-000000010" / "model"
    model.mkdir(parents=True)
    (model.parent / "state.json").write_text(json.dumps({"step": 10, "stage_config": {"cache": str(cache)}}))
    assert training_size(model) == (160, 112)
    (model / "training.json").write_text(json.dumps({"size": [96, 64]}))
    assert training_size(model) == (96, 64)
    assert training_size(tmp_path) is None


def test_conditions_mask_text_drop_reference():
    from x2video.conditioning.edited import apply_edits

    shot = tiny_room(3, frames=4, size=(32, 24))
    edits, desc = build_edits(shot, "r3", Condition("mask_amr", text=True, masks=2), seed=5)
    objs = [int(k) for k in desc["objects"]]
    assert len(objs) == 2 and objs == pick_objects(shot, "r3", 2, 5)
    assert desc["local_prompts"] == [shot.info.object_captions[i] for i in objs]
    assert desc["global_prompt"] == shot.info.caption
    cond = apply_edits(shot, edits, 2)
    inside = np.isin(shot.channel("ids", 2)[..., 0], objs)
    assert inside.any() and (cond.channels["albedo"][inside] == 0).all() and (cond.channels["roughness"][inside] == 0).all()
    np.testing.assert_array_equal(cond.amr_mask > 0.5, inside)
    np.testing.assert_array_equal(cond.channels["irradiance"], shot.channel("irradiance", 2))
    assert cond.local_masks.shape == (2, 24, 32)
    drop, _ = build_edits(shot, "r3", Condition("drop_irradiance", reference=True), seed=5)
    c2 = apply_edits(shot, drop, 0)
    assert c2.channels["irradiance"] is None and drop.reference.frame == 0 and drop.global_prompt == ""
    assert build_edits(shot, "r3", Condition("full"), seed=5)[0] is None
    with pytest.raises(ValueError, match="unknown condition"):
        Condition("mask_everything")


def _row(label, psnr, tc=1.1, spf=1.0, b_psnr=20.0, kind="full", ref=False, sampler="ddim", available=True):
    return {"label": label, "available": available, "condition": {"kind": kind, "text": False, "reference": ref},
            "settings": {"sampler": sampler},
            "model": {"psnr": psnr, "tc": tc, "seconds_per_frame": spf, "ssim": 0.9, "fid": 10.0},
            "baseline": {"psnr": b_psnr, "tc": 1.0, "ssim": 0.8, "fid": 20.0}}


def _results():
    return {"format": "x2video-eval", "tables": {
        "a": {"title": "A", "rows": [_row("Image model (per frame)", 20.0, tc=2.0), _row("Video model", 22.0, tc=1.05)]},
        "b": {"title": "B", "rows": [_row("Full channels", 22.0), _row("Mask A|M|R", 19.0, kind="mask_amr", b_psnr=15.0),
                                     _row("Mask A|M|R + Text", 19.5, kind="mask_amr", b_psnr=15.0),
                                     _row("Mask A|M|R + Ref.", 18.0, kind="mask_amr", b_psnr=15.0)]},
        "d": {"title": "D", "rows": [_row("DDIM-20", 22.0, spf=1.0), _row("LCM-2", 21.0, spf=0.15, sampler="lcm")]},
    }, "models": {"video": {"path": "runs/video/step-000000100/model", "config": "tiny", "step": 100}}}


def test_orderings_report_what_holds():
    res = _results()
    checks = {c["claim"]: c["holds"] for c in orderings(res)}
    assert checks["(a) video model TC < image model per frame TC"] is True
    assert checks["(b) Mask A|M|R lowers PSNR below full channels"] is True
    assert checks["(b) Mask A|M|R + Text recovers PSNR"] is True
    assert checks["(b) Mask A|M|R + Ref. recovers PSNR"] is False
    assert checks["(b) Drop irradiance lowers PSNR below full channels"] is None  # rows absent: not measured
    assert checks["(d) LCM is >= 5x faster per frame than DDIM (LCM s/frame x 5 <= DDIM s/frame)"] is True
    assert checks["(a) Video model: model PSNR >= classical baseline PSNR"] is True
    assert checks["(b) Mask A|M|R + Ref.: model PSNR > classical baseline PSNR"] is True
    assert checks["(d) ... both with the reference frame (the paper's pair: Ref-First vs Ref-First + LCM 2-step)"] is None
    # per-shot agreement: a mean ordering that only some shots share is flagged, not hidden
    full, masked = res["tables"]["b"]["rows"][0], res["tables"]["b"]["rows"][1]
    full["model"]["shots"] = {"s1": {"psnr": 23.0}, "s2": {"psnr": 21.0}, "s3": {"psnr": 22.0}}
    masked["model"]["shots"] = {"s1": {"psnr": 18.0}, "s2": {"psnr": 21.5}, "s4": {"psnr": 1.0}}
    masked["baseline"]["shots"] = {"s1": {"psnr": 10.0}, "s2": {"psnr": 22.0}}
    res["tables"]["d"]["rows"] += [_row("DDIM-20 + Ref.", 22.0, spf=1.2, ref=True), _row("LCM-2 + Ref.", 21.0, spf=0.25, sampler="lcm", ref=True)]
    by_claim = {c["claim"]: c for c in orderings(res)}
    lower = by_claim["(b) Mask A|M|R lowers PSNR below full channels"]
    assert lower["holds"] is True and lower["shots"] == "1/2"  # s1 lower, s2 higher; s3/s4 not in both
    assert by_claim["(b) Mask A|M|R: model PSNR > classical baseline PSNR"]["shots"] == "1/2"
    assert "shots" not in by_claim["(a) video model TC < image model per frame TC"]  # no per-shot numbers
    assert by_claim["(d) ... both with the reference frame (the paper's pair: Ref-First vs Ref-First + LCM 2-step)"]["holds"] is False
    assert "| 1/2 |" in orderings_markdown(list(by_claim.values()))
    # (d): each shot's own speed-up (5 x LCM s/frame < DDIM s/frame)
    ddim, lcm = res["tables"]["d"]["rows"][0], res["tables"]["d"]["rows"][1]
    ddim["model"]["shots"] = {"s1": {"seconds_per_frame": 1.0}, "s2": {"seconds_per_frame": 1.0}, "s3": {"seconds_per_frame": 1.0}}
    lcm["model"]["shots"] = {"s1": {"seconds_per_frame": 0.15}, "s2": {"seconds_per_frame": 0.21}, "s3": {"seconds_per_frame": 0.19}}
    assert next(c for c in orderings(res) if c["claim"].startswith("(d) LCM is"))["shots"] == "2/3"


def test_table_c_under_several_conditions_pairs_each_schemes_rows():
    from x2video.eval.conditions import Condition, parse_condition
    from x2video.eval.config import EvalConfig
    from x2video.eval.tables import table_rows

    rows = table_rows(EvalConfig(tables=("c",), long_conditions=("full", "drop_irradiance")))["c"]
    assert [(r.label, r.scheme, r.condition.kind, r.data) for r in rows] == [
        ("Sequential", "sequential", "full", "long"), ("Recursive", "recursive", "full", "long"),
        ("Sequential, Drop irradiance", "sequential", "drop_irradiance", "long"),
        ("Recursive, Drop irradiance", "recursive", "drop_irradiance", "long"),
    ]
    with pytest.raises(ValueError, match="long_conditions.*choose from"):
        EvalConfig(long_conditions=("no_albedo",))
    with pytest.raises(ValueError, match="long_conditions.*\\+ref"):
        EvalConfig(long_conditions=("full+reff",))
    rows = table_rows(EvalConfig(tables=("c",), long_conditions=("full+ref", "mask_amr+text+ref"), masks=2))["c"]
    assert [(r.label, r.condition) for r in rows[::2]] == [
        ("Sequential, Full channels + Ref.", Condition("full", False, True, 2)),
        ("Sequential, Mask A|M|R + Text + Ref.", Condition("mask_amr", True, True, 2)),
    ]
    assert parse_condition(" drop_irradiance+ref ").token == "drop_irradiance+ref"
    for bad in ("ref", "full+ref+ref", "mask_amr+refs", ""):
        with pytest.raises(ValueError, match="KIND\\[\\+text\\]\\[\\+ref\\]"):
            parse_condition(bad)
    c = {"title": "C", "rows": [_row("Sequential", 25.0, tc=3.0), _row("Recursive", 24.0, tc=2.0),
                                _row("Sequential, Drop irradiance", 14.0, tc=5.0), _row("Recursive, Drop irradiance", 15.0, tc=4.0)]}
    for r in c["rows"]:
        r["settings"]["scheme"] = "recursive" if r["label"].startswith("Recursive") else "sequential"
        r["condition"]["kind"] = "drop_irradiance" if "Drop" in r["label"] else "full"
    checks = {x["claim"]: x["holds"] for x in orderings({"tables": {"c": c}})}
    assert checks["(c) recursive PSNR > sequential PSNR"] is False
    assert checks["(c) recursive TC < sequential TC"] is True
    assert checks["(c) recursive PSNR > sequential PSNR, Drop irradiance"] is True
    assert checks["(c) recursive TC < sequential TC, Drop irradiance"] is True


def test_table_c_psnr_by_quarter_pairs_schemes_per_condition():
    from x2video.eval.report import psnr_by_part, table_markdown

    def row(label, scheme, ref, shots):
        r = _row(label, 0.0, ref=ref)
        r["settings"]["scheme"] = scheme
        r["model"]["shots"] = {f"room_{i}": {"psnr_frames": f} for i, f in enumerate(shots)}
        return r

    flat = [20.0] * 9  # 9 frames: quarters of 3, 2, 2, 2 frames (numpy.array_split)
    drift = [20.0, 20.0, 20.0, 19.0, 19.0, 18.0, 18.0, 16.0, 16.0]
    rows = [row("Sequential, Full channels + Ref.", "sequential", True, [drift, drift]),
            row("Recursive, Full channels + Ref.", "recursive", True, [flat, [22.0] * 9]),
            row("Sequential", "sequential", False, [flat, flat]),
            row("Recursive", "recursive", False, [flat, flat])]
    assert psnr_by_part(rows[0]) == [20.0, 19.0, 18.0, 16.0]
    assert psnr_by_part(rows[1]) == [21.0] * 4  # mean over shots
    assert psnr_by_part(row("short", "recursive", False, [[20.0] * 3])) is None
    md = table_markdown("c", {"title": "C", "rows": rows})
    assert "| Recursive − sequential, Full channels + Ref. | +1.00 | +2.00 | +3.00 | +5.00 |" in md
    assert "| Recursive − sequential | +0.00 | +0.00 | +0.00 | +0.00 |" in md  # paired by condition, not row order
    assert "quarter" not in table_markdown("b", {"title": "B", "rows": rows})


def test_markdown_rows_escape_bars_and_show_missing_models():
    line = row_line(_row("Mask A|M|R", 19.0))
    assert line.startswith("| Mask A\\|M\\|R |")
    cells = [c for c in line.replace("\\|", "/").split("|")][1:-1]
    assert len(cells) == 13 and cells[2].strip() == "n/a¹" and cells[3].strip() == "19.00"
    missing = row_line({"label": "LCM-2", "available": False, "reason": "no LCM weights"})
    assert "n/a: no LCM weights" in missing and len(missing.split("|")) - 2 == 13
    md = results_markdown(_results())
    assert "### (a) A" in md and "### (d) D" in md and "re-estimates its reference frames (`--no-replace-refs`)" in md  # results without the setting
    assert "held at their noised latents between steps (`--replace-refs`)" in results_markdown(dict(_results(), settings={"replace_refs": True}))
    assert "Initial noise: per window (`--noise window`)" in md  # results from before the option
    framed = results_markdown(dict(_results(), settings={"noise": "frame", "noise_shared": 0.95}))
    assert "per frame of the shot (`--noise frame`), 0.95 of its variance shared by all frames (`--noise-shared 0.95`)" in framed
    assert "--max-levels" not in md
    assert "at most 2 levels (`--max-levels 2`)" in results_markdown(dict(_results(), settings={"max_levels": 2}))


def test_model_card_from_results_and_runs(tmp_path, capsys):
    from x2video.eval import card

    res = tmp_path / "eval"
    res.mkdir()
    (res / "results.json").write_text(json.dumps(dict(_results(), command="x2video eval --weights W --data D --out eval")))
    run = tmp_path / "vae_run"
    ck = run / "step-000000200"
    ck.mkdir(parents=True)
    (ck / "state.json").write_text(json.dumps({"step": 200, "loop": {"lr": 2e-4}, "stage_config": {"stage": "vae", "batch": 16}}))
    (run / "summary.json").write_text(json.dumps({"steps_run": 100, "seconds": 50.0, "steps_per_s": 2.0, "samples_per_s": 32.0,
                                                  "device": "cpu"}))
    (run / "log.json").write_text(json.dumps([{"step": i + 1, "loss": 0.1, "steps_per_s": 2.0} for i in range(200)]))
    (run / "results.json").write_text(json.dumps({"vae": {"heldout_psnr_db": {"rgb": 31.5, "albedo": 35.25}}}))
    img = tmp_path / "image_run"
    (img / "step-000000050").mkdir(parents=True)
    (img / "step-000000050" / "state.json").write_text(json.dumps({"step": 50, "loop": {}, "stage_config": {"stage": "image"}}))
    (img / "results.json").write_text(json.dumps({"image": {"shading_prior": False, "heldout_v_loss": {"full": 0.1571, "augmented": 0.1893}}}))
    pre = tmp_path / "preface.md"
    pre.write_text("## Data\n\nmade with `x2video dataset make`\n")
    out = tmp_path / "MODEL_CARD.md"
    assert card.main([str(res), "--run", str(run), "--run", str(img), "--preface", str(pre), "--out", str(out)]) == 0
    text = out.read_text()
    assert "| vae | `" in text and "| 200 |" in text and "rgb 31.50 dB" in text
    assert "shading prior off; held-out v-loss full 0.1571, augmented 0.1893" in text
    assert text.index("## Data") < text.index("## Training")
    hours = 200 * 0.5 / 3600
    assert f"{hours:.3g}" in text
    assert "x2video eval --weights W --data D --out eval" in text and "| ordering | holds | measured |" in text
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "results.json").write_text(json.dumps({"vae": {}}))
    assert card.main([str(bad)]) == 2 and "not an `x2video eval` results file" in capsys.readouterr().err


def _speedup_bench(ratios: list[tuple[float, float, float]], threads: int = 2) -> dict:
    """A bench/lcm_speedup.py result whose repeats have these (speedup, speedup_ref, speedup_no_encoding)."""
    import statistics

    names = ("DDIM-20", "DDIM-20 + Ref.", "LCM-2", "LCM-2 + Ref.")
    reps = [{"order": ["ddim", "lcm"], "speedup": a, "speedup_ref": b, "speedup_no_encoding": c, "speedup_ref_no_encoding": c,
             "rows": [{"name": n, "seconds_per_frame": 1.0, "encode_seconds_per_frame": 0.1} for n in names]} for a, b, c in ratios]
    keys = ("speedup", "speedup_ref", "speedup_no_encoding", "speedup_ref_no_encoding")
    return {"format": "x2video-lcm-speedup", "command": "python bench/lcm_speedup.py --data D", "wall_seconds": 10.0,
            "machine": {"cpu": "cpu", "cpu_cores": 2, "torch_threads": threads}, "data": {"rooms": ["a", "b"], "frames": 17},
            "repeats": reps, "median": {k: statistics.median(r[k] for r in reps) for k in keys}}


def test_speedup_ordering_from_back_to_back_repeats(tmp_path, capsys):
    """(d) from bench/lcm_speedup.py: holds on the median ratio, and says in how many repeats it holds."""
    from x2video.eval import card
    from x2video.eval.checks import speedup_checks

    checks = {c["claim"]: c for c in speedup_checks(_speedup_bench([(4.9, 5.6, 8.0), (5.4, 5.5, 8.5), (6.1, 4.8, 9.8)]))}
    plain = checks["(d) LCM is >= 5x faster per frame than DDIM, back to back"]
    assert plain["holds"] is True and plain["shots"] == "2/3 repeats" and "median 5.40x (min 4.90, max 6.10)" in plain["values"]
    ref = checks["(d) ... both with the reference frame (the paper's pair), back to back"]
    assert ref["holds"] is True and ref["shots"] == "2/3 repeats"
    low = speedup_checks(_speedup_bench([(4.2, 4.8, 7.0), (4.6, 5.0, 7.5)]))
    assert [c["holds"] for c in low] == [False, True, False]  # median 4.4, 7.25, 4.9
    res = tmp_path / "eval"
    res.mkdir()
    (res / "results.json").write_text(json.dumps(dict(_results(), command="x2video eval --data D --out eval")))
    bench = tmp_path / "lcm_speedup.json"
    bench.write_text(json.dumps(_speedup_bench([(5.4, 5.5, 8.5)], threads=1)))
    out = tmp_path / "card.md"
    assert card.main([str(res), "--speedup", str(bench), "--out", str(out)]) == 0
    text = out.read_text()
    assert "## LCM-2 vs DDIM-20 back to back, 1 torch thread\n" in text and "| 1 | ddim then lcm | 1.000 (0.100) |" in text
    assert "| (d) LCM is >= 5x faster per frame than DDIM, back to back | yes | median 5.40x" in text
    bf16 = dict(_speedup_bench([(5.6, 5.7, 8.5)], threads=2), weights={"video": {"encoder_dtype": "bfloat16"}})
    bench2 = tmp_path / "lcm_speedup_bf16.json"
    bench2.write_text(json.dumps(bf16))
    assert card.main([str(res), "--speedup", str(bench), "--speedup", str(bench2), "--out", str(out)]) == 0
    assert "## LCM-2 vs DDIM-20 back to back, 2 torch threads, VAE encoder in bfloat16\n" in out.read_text()
    bench2.write_text(json.dumps(dict(bf16, weights={"video": {"channel_encoder": "distilled"}})))
    assert card.main([str(res), "--speedup", str(bench), "--speedup", str(bench2), "--out", str(out)]) == 0
    assert "## LCM-2 vs DDIM-20 back to back, 2 torch threads, channels through the distilled encoder\n" in out.read_text()
    gpu = _speedup_bench([(6.1, 6.0, 9.0)], threads=16)
    gpu["machine"].update(device="cuda", cuda="NVIDIA H200")
    bench2.write_text(json.dumps(gpu))
    assert card.main([str(res), "--speedup", str(bench2), "--out", str(out)]) == 0
    assert "## LCM-2 vs DDIM-20 back to back, on NVIDIA H200\n" in out.read_text()
    bench.write_text(json.dumps({"format": "x2video-eval"}))
    assert card.main([str(res), "--speedup", str(bench)]) == 2 and "not a `bench/lcm_speedup.py` result" in capsys.readouterr().err


def test_card_log_adds_dated_entries_and_the_card_quotes_them(tmp_path, capsys):
    """--log: one dated file per evaluation and speed-up, numbered on, machine paths scrubbed; --card: the
    source with its headline lines replaced by the entry's table, the formula's columns beside each row."""
    from x2video.eval import card

    res = tmp_path / "eval"
    res.mkdir()
    (res / "results.json").write_text(json.dumps(dict(_results(), command="x2video eval --data /mnt/data/r160 --out eval")))
    bench = tmp_path / "b.json"
    bench.write_text(json.dumps(dict(_speedup_bench([(5.6, 5.7, 8.5)], threads=2), weights={"video": {"encoder_dtype": "bfloat16"}})))
    log = tmp_path / "log"
    log.mkdir()
    (log / "2026-01-01-evaluation-07.md").write_text("# Evaluation 7 (2026-01-01)\n")
    assert card.main([str(res), "--speedup", str(bench), "--log", str(log)]) == 0
    entries = sorted(p.name for p in log.glob("*-*.md"))
    date = entries[-1][:10]
    assert entries == ["2026-01-01-evaluation-07.md", f"{date}-evaluation-08.md", f"{date}-speedup-01.md"]
    text = (log / f"{date}-evaluation-08.md").read_text()
    assert text.startswith(f"# Evaluation 8 ({date})\n\nAdded by `python -m x2video.eval.card ")
    assert "--data DATA/r160" in text and "/mnt/" not in text and "| ordering | holds | measured |" in text
    assert "Speed-up 1" in (log / f"{date}-speedup-01.md").read_text()
    assert f"[{date}-evaluation-08]({date}-evaluation-08.md)" in (log / "README.md").read_text()
    source = tmp_path / "card.md"
    source.write_text(f"# Card\n\n<!-- headline {date}-evaluation-08.md (a) -->\n\nLimits.\n")
    out = tmp_path / "res" / "MODEL_CARD.md"
    assert card.main(["--card", str(source), "--log", str(log), "--out", str(out)]) == 0
    built = out.read_text()
    assert "| PSNR↑ | SSIM↑ | TC↓ | s/frame↓ | formula PSNR↑ | formula TC↓ |" in built and "Limits." in built
    assert f"(../log/{date}-evaluation-08.md)" in built and "Reproduce: `x2video eval --data DATA/r160" in built
    source.write_text("<!-- headline 2026-01-01-evaluation-09.md (a) -->\n")
    assert card.main(["--card", str(source), "--log", str(log), "--out", str(out)]) == 2 and "does not exist" in capsys.readouterr().err
    with pytest.raises(SystemExit):  # no results and no card: nothing to do
        card.main([])


def test_shipped_card_is_built_whole_from_its_source_and_fits_a_few_screens():
    from x2video.eval.card import build_card

    root = Path(__file__).resolve().parents[1]
    shipped = (root / "resources" / "MODEL_CARD.md").read_text(encoding="utf-8")
    import os

    cwd = os.getcwd()
    os.chdir(root)
    try:
        built = build_card(Path("docs/model_card.md"), Path("docs/evaluations"), Path("resources/MODEL_CARD.md"))
    finally:
        os.chdir(cwd)
    assert shipped == built, "resources/MODEL_CARD.md is stale: python -m x2video.eval.card --card docs/model_card.md"
    assert len(shipped.splitlines()) <= 200
    # the shipped tiers' rows on the outside scenes: tier 1's table and the diffusion tier's, the truth they scored
    # against and the formula's column beside each
    import json

    from bench.card import SOURCES

    src = json.loads((root / SOURCES["outside"]).read_text())
    rows = [ln for ln in shipped.splitlines() if ln.startswith("| hand-written outside scenes")]
    want = (src["truth"], f"{src['summary']['formula|all']['psnr']:.2f}")
    assert len(rows) == 2 and all((r.split("|")[2].strip(), r.split("|")[3].strip()) == want for r in rows), (rows, want)
    assert want[0].startswith("apart, ")  # scored against a truth rendered apart from the passes (issue 49)


def test_contact_sheet_and_mp4(tmp_path):
    from x2video.eval.contact import contact_sheet, pick_frames, write_comparison

    rng = np.random.default_rng(0)
    seq = [rng.uniform(0, 1, (12, 16, 3)).astype(np.float32) for _ in range(7)]
    assert pick_frames(7, 5) == [0, 2, 3, 4, 6] and pick_frames(3, 5) == [0, 1, 2]
    sheet = contact_sheet([("gt", seq), ("video", seq)], [0, 3, 6])
    assert sheet.dtype == np.uint8 and sheet.shape == (2 * (14 + 12), 3 * 16 + 2 * 2, 3)
    png, mp4 = write_comparison(tmp_path, "shot", [("gt", seq), ("video", seq)], fps=5)
    assert png.stat().st_size > 0 and mp4.stat().st_size > 0
    with pytest.raises(ValueError, match="frame 9 asked"):
        contact_sheet([("gt", seq)], [9])


def test_speed_accuracy_chart_and_editor_shape(tmp_path):
    mod = importlib.import_module("bench.speed_accuracy")
    result = {"machine": {"cpu": "test cpu", "cpu_cores": 2, "torch_threads": 1, "device": "cpu"},
              "rows": [{"name": "DDIM-20", "seconds_per_frame": 2.0, "psnr": 24.0}, {"name": "DDIM-4", "seconds_per_frame": 0.5, "psnr": 23.0},
                       {"name": "classical shading", "seconds_per_frame": 0.03, "psnr": 20.0}],
              "unavailable": [{"preset": "LCM-2", "reason": "none"}]}
    png = mod.draw_chart(result, tmp_path / "speed_accuracy.png")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    (tmp_path / "speed_accuracy.json").write_text(json.dumps(result))
    from x2video_app._qt.charts import load_bench_points

    pts = load_bench_points(tmp_path)
    assert [p[0] for p in pts] == ["DDIM-20", "DDIM-4", "classical shading"] and all(math.isfinite(p[2]) for p in pts)


def test_speed_accuracy_chart_moves_touching_labels_below():
    """LCM-2 (0.48 s, 24.75 dB) and DDIM-4 (0.65 s, 24.72 dB) of the shipped model's run: DDIM-4's
    label, above-right of its point, would cover LCM-2's; far apart points keep theirs above."""
    from x2video.eval.report import labels_below

    pts = [("DDIM-20", 2.44, 24.94), ("DDIM-4", 0.65, 24.72), ("LCM-2", 0.479, 24.75), ("DDIM-20, no detail", 2.14, 21.37),
           ("classical shading", 0.007, 24.54)]
    assert labels_below(pts) == {1}  # DDIM-4
    assert labels_below([("a", 0.1, 20.0), ("b", 1.0, 20.0), ("c", 0.12, 25.0)]) == set()
    lin = [("a", 0.48, 24.75), ("b", 0.65, 24.72), ("c", 2.4, 24.9), ("d", 2.1, 21.4)]
    assert labels_below(lin, log_x=False) == {1}  # 0.17 s apart on a 2.3 s linear axis
    assert labels_below([]) == set()


def test_resolve_size_prefers_a_smaller_training_size(tmp_path):
    import argparse

    from eval_fixtures import make_dataset

    from x2video.cli.eval import resolve_size

    data = make_dataset(tmp_path / "d", frames=2, size=(64, 48))
    model = tmp_path / "m"
    model.mkdir()
    a = argparse.Namespace(data=data, split="test", size=None)
    assert resolve_size(a, model, 8) == ((64, 48), "the data's size (the weights do not record a training size)")
    (model / "training.json").write_text(json.dumps({"size": [32, 24]}))
    size, why = resolve_size(a, model, 8)
    assert size == (32, 24) and "trained at 32x24" in why and "area-downsampled from 64x48" in why
    (model / "training.json").write_text(json.dumps({"size": [128, 96]}))
    assert resolve_size(a, model, 8)[0] == (64, 48)
    with pytest.raises(ValueError, match="not a multiple of the model's VAE factor 8"):
        resolve_size(argparse.Namespace(data=data, split="test", size=(60, 48)), model, 8)


def test_recursive_seams_classifies_pairs_by_the_windows_that_made_them():
    from x2video.sampling.planner import plan

    mod = importlib.import_module("bench.recursive_seams")
    # recursive, 17 frames, N = 5: one keyframe window (level 2) makes 0, 4, 8, 12, 16; level-1 windows the rest
    rec = mod.pair_classes(plan("recursive", 17, 5), 17)
    assert rec[:4] == ["seam, level 2", "same window", "same window", "seam, level 2"]
    assert rec.count("seam, level 2") == 8 and rec.count("same window") == 8
    # 65 frames: keyframes at stride 16 (level 3), stride-4 frames from level-2 windows
    rec65 = mod.pair_classes(plan("recursive", 65, 5), 65)
    assert rec65[0] == rec65[15] == "seam, level 3" and rec65[3] == rec65[4] == "seam, level 2" and rec65[1] == "same window"
    # sequential: windows make 0-4, 5-8, 9-12, ...: a seam after every 4th frame, all level 1
    seq = mod.pair_classes(plan("sequential", 17, 5), 17)
    assert [i for i, c in enumerate(seq) if c != "same window"] == [4, 8, 12] and set(seq) == {"same window", "seam, level 1"}
    # the seam pass: the level-2 windows that make the keyframes again become their makers (the last window wins)
    seams = mod.pair_classes(plan("recursive", 65, 5, seams=True), 65)
    assert "seam, level 3" not in seams and seams[15] == seams[16] == "seam, level 2" and seams[13] == "same window"
    # sides: sequential seams all lie after a window's first reference; recursive ones on both sides
    assert set(mod.pair_sides(plan("sequential", 17, 5), 17)) == {"same window", "start"}
    sides = mod.pair_sides(plan("recursive", 17, 5), 17)
    assert sides[:4] == ["start", "same window", "same window", "end"] and sides.count("start") == sides.count("end") == 4
    # the keyframe window made 0 and 16 and reads neither of its level-1 neighbours' frames
    assert mod.pair_sides(plan("recursive", 65, 5), 65)[15] == "end" and "other" not in mod.pair_sides(plan("recursive", 65, 5), 65)


def test_eval_command_line_reproduces_every_setting():
    """The results' Reproduce command carries the sampler options that change the renders."""
    from x2video.cli import build_parser
    from x2video.cli.eval import command_line

    base = ["eval", "--data", "d", "--out", "o", "--tables", "c", "--long-conditions", "full+ref"]
    a = build_parser().parse_args(base)  # on by default, and written out: the default changed once
    assert a.replace_refs and " --replace-refs" in command_line(a)
    assert "--long-conditions full+ref --tables c" in command_line(a)
    off = build_parser().parse_args(base + ["--no-replace-refs"])
    assert not off.replace_refs and "--no-replace-refs" in command_line(off) and " --replace-refs" not in command_line(off)
    assert command_line(build_parser().parse_args(command_line(off).split()[1:])) == command_line(off)
    assert " --channel-encoder auto " in command_line(a)  # the encoder is part of what a timing means
    distilled = build_parser().parse_args(base + ["--channel-encoder", "distilled"])
    assert command_line(build_parser().parse_args(command_line(distilled).split()[1:])) == command_line(distilled)
    assert "--threads" not in command_line(a) and "--threads 1 --out o" in command_line(build_parser().parse_args(base + ["--threads", "1"]))
    assert command_line(build_parser().parse_args(command_line(a).split()[1:])) == command_line(a)  # a fixed point
    assert " --seams" in command_line(a) and "--bf16-encoder" not in command_line(a)  # the seam pass is on by default
    assert " --ref-dc 1 " in command_line(a)
    on = build_parser().parse_args(base + ["--no-seams", "--bf16-encoder"])
    assert not on.seams and on.bf16_encoder and " --no-seams" in command_line(on) and " --bf16-encoder" in command_line(on)
    assert command_line(build_parser().parse_args(command_line(on).split()[1:])) == command_line(on)
    assert " --noise frame --noise-shared 0.95 " in command_line(a)  # RenderSettings' defaults, written out
    assert "--resample" not in command_line(a)  # off by default
    dc = build_parser().parse_args(base + ["--ref-dc", "0.5"])
    assert dc.ref_dc == 0.5 and " --ref-dc 0.5 " in command_line(dc)
    assert command_line(build_parser().parse_args(command_line(dc).split()[1:])) == command_line(dc)
    rs = build_parser().parse_args(base + ["--resample", "2"])
    assert rs.resample == 2 and " --resample 2 " in command_line(rs)
    assert command_line(build_parser().parse_args(command_line(rs).split()[1:])) == command_line(rs)
    win = build_parser().parse_args(base + ["--noise", "window"])
    assert " --noise window " in command_line(win) and "--noise-shared" not in command_line(win)
    half = build_parser().parse_args(base + ["--noise-shared", "0.5"])
    assert half.noise_shared == 0.5 and command_line(build_parser().parse_args(command_line(half).split()[1:])) == command_line(half)
    assert "--max-levels" not in command_line(a)  # None: as many levels as the shot needs
    capped = build_parser().parse_args(base + ["--max-levels", "2"])
    assert capped.max_levels == 2 and " --seams --max-levels 2 " in command_line(capped)
    assert command_line(build_parser().parse_args(command_line(capped).split()[1:])) == command_line(capped)
