"""bench.edits_terms: the oracle swaps of an albedo edit's rebuild are exact where their term is the whole change."""
from __future__ import annotations

import numpy as np

from bench.edits_terms import NAMES, variants


def _passes(rng, diffcol):
    p = {n: rng.uniform(0.05, 0.5, (6, 8, 3)).astype(np.float32) for n in NAMES}
    p["DiffCol"] = np.broadcast_to(np.float32(diffcol), (6, 8, 3)).copy()
    p["Combined"] = p["DiffCol"] * (p["DiffDir"] + p["DiffInd"]) + p["GlossCol"] * (p["GlossDir"] + p["GlossInd"]) + p["Emit"] + p["Env"]
    return p


def test_each_oracle_recovers_the_re_render_where_only_its_term_changed():
    rng = np.random.default_rng(0)
    b = _passes(rng, (0.2, 0.1, 0.05))
    colour = np.float32([0.8, 0.5, 0.1])
    a = {k: v.copy() for k, v in b.items()}
    a["DiffCol"][:] = colour
    a["Combined"] = b["Combined"] + (colour - b["DiffCol"]) * (b["DiffDir"] + b["DiffInd"])
    v = variants(b, a, colour)
    for name in ("rebuild from passes (the floor)", "oracle: re-render's diffuse colour", "oracle: re-render's colour, diffuse light and glossy term"):
        np.testing.assert_allclose(v[name], a["Combined"], rtol=1e-5, atol=1e-6)
    a2 = {k: x.copy() for k, x in a.items()}
    a2["DiffInd"] = a["DiffInd"] * 1.5  # the object lights itself more once brighter: only the diffuse-light oracle has it
    a2["Combined"] = a["Combined"] + colour * a["DiffInd"] * 0.5
    v2 = variants(b, a2, colour)
    np.testing.assert_allclose(v2["oracle: re-render's diffuse light"], a2["Combined"], rtol=1e-5, atol=1e-6)
    assert np.abs(v2["rebuild from passes (the floor)"] - a2["Combined"]).max() > 0.01
