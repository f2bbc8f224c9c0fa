"""What a chart row's inputs cost to make (issue 49): the tiers read passes that are themselves a path trace.

Every tier reads irradiance, which is Cycles' diffuse light passes: on our sets it comes out of the same render as
the beauty (bench/results/pareto/input_cost.json records what that render cost per frame). A user editing an
existing shot has them already ("already rendered"); a user who must render them for this pays them on every
frame ("rendered for this"). Cycles' own rows read nothing but the scene.
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any

COSTS = Path(__file__).resolve().parent.parent / "results" / "pareto" / "input_cost.json"


def input_costs(path: Path = COSTS) -> dict[str, dict[str, Any]]:
    """size 'WxH' -> the passes' cost record ({} when none is committed)."""
    return json.loads(path.read_text())["sizes"] if path.is_file() else {}


def input_cost(row: dict, costs: dict[str, dict[str, Any]]) -> dict[str, Any] | None:
    """The inputs of `row` and their CPU seconds per frame, or None for a row that reads no passes (Cycles)."""
    if row["kind"] == "cycles":
        return None
    rec = costs.get(f"{row['size'][0]}x{row['size'][1]}")
    if rec is None:
        return {"what": "the passes (cost not measured at this size)", "cpu_seconds_per_frame": None}
    return {"what": rec["what"], "cpu_seconds_per_frame": rec["cpu_seconds_per_frame"]}


def with_inputs(row: dict, costs: dict[str, dict[str, Any]]) -> dict[str, Any]:
    """`row` with `inputs` (None for Cycles) and `seconds_rendered_for_this` (its own seconds plus the passes')."""
    cost = input_cost(row, costs)
    own = row["seconds_per_frame"]
    total = own + cost["cpu_seconds_per_frame"] if cost and cost["cpu_seconds_per_frame"] is not None else (own if cost is None else None)
    return {**row, "inputs": cost, "seconds_rendered_for_this": total}
