"""bench.stability's cells (bench/stability_cells.py) on a few tiny cells: numbers recorded, no crash (a fake model, a synthetic shot)."""
from __future__ import annotations

import math

import pytest
from test_tiers import with_net

from bench import stability as S
from bench import stability_cells as C
from bench.stability_shots import SyntheticShot


@pytest.fixture(scope="module")
def ctx():
    c = C.Context([SyntheticShot(4, (24, 32))])
    c._model = with_net()  # FakeModel (diffusion) with a tier-1 net: no weights to load
    return c


def cell(family: str, name: str, method: str, **params) -> dict:
    return {"family": family, "name": name, "method": method, "params": {"frames": 2, **params}}


@pytest.mark.parametrize("method", ["formula", "auto"])
@pytest.mark.parametrize("family,name,params", [
    ("hostile", "nan_irradiance", {"case": "nan_irradiance"}),
    ("size", "8x8", {"size": [8, 8]}),
    ("channels", "alb+nor+rou+met", {"kept": ["albedo", "normal", "roughness", "metallic"]}),
    ("limits", "shot0", {}),
])
def test_cells_record_numbers_without_crashing(ctx, method, family, name, params):
    rec = C.run_cell(cell(family, name, method, **params), ctx)
    assert not rec["crashed"], rec["error"]
    assert rec["frames_out"] == 2 and rec["frames_missing"] == 0
    assert math.isfinite(rec["psnr"]) and rec["nonfinite_frac"] == 0.0
    assert rec["seconds"] >= 0 and rec["peak_rss_mb"] > 0
    if family == "limits":
        assert set(rec["psnr_by_class"]) == set(C.CLASS_SETS["limits"])
    if method == "auto":
        assert rec["tier"] == ("residual" if family != "channels" else "diffusion")
    if min(rec["size"]) >= 12:
        assert rec["tc"] is not None


def test_length_cell_measures_drift_and_a_crash_is_recorded(ctx):
    rec = C.run_cell(cell("length", "3f", "formula", frames=3), ctx)
    assert rec["delta_e"] > 0 and len(rec["delta_e_series"]) == 3
    bad = C.run_cell(cell("nope", "x", "formula"), ctx)
    assert bad["crashed"] and "unknown family" in bad["error"]


def test_quick_grid_covers_every_family_and_skips_big_diffusion():
    cells = S.grid(True, 2, True, S.FAMILIES, S.METHODS)
    assert {c["family"] for c in cells} == set(S.FAMILIES)
    c = C.Context([SyntheticShot()])
    big = [x for x in cells if x["method"] == "diffusion" and x["params"].get("size") == [1920, 1080]]
    # 1920x1080 runs at the diffusion tier's working size (the default cap); above a lower cap it is skipped, saying why
    assert big and not any(C.skip_reason(x, c) for x in big)
    capped = C.Context([SyntheticShot()], diffusion_max_pixels=640 * 360)
    assert all("--diffusion-max-pixels" in C.skip_reason(x, capped) for x in big)
    assert len(S.grid(False, 6, True, ("channels",), ("formula",))) == 32


def test_merge_results_later_cells_replace_earlier():
    a = {"command": "a", "wall_seconds": 1.0, "cells": [
        {"family": "hostile", "name": "x", "method": "diffusion", "crashed": True, "error": "E"},
        {"family": "hostile", "name": "x", "method": "formula", "crashed": False, "psnr": 20.0}]}
    b = {"command": "b", "wall_seconds": 2.0, "cells": [
        {"family": "hostile", "name": "x", "method": "diffusion", "crashed": False, "psnr": 19.0}]}
    m = S.merge_results([a, b])
    assert len(m["cells"]) == 2 and m["cells"][0]["psnr"] == 19.0 and m["command"] == "a ; b" and m["wall_seconds"] == 3.0
    assert m["findings"] == [] and S.findings(a["cells"])[0]["failure"] == "crash"
