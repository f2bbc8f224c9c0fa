"""bench/results/README.md and docs/evaluations/README.md are written by `python -m bench.index` (issue 50 item 6,
issue 49 item 5): every file listed, in date order, each with a title; the committed text is what the files give."""
from __future__ import annotations

import re

import pytest

from bench import index


def test_committed_indexes_are_what_the_files_give():
    for path, text in index.expected(index.load_dates()).items():
        assert path.read_text(encoding="utf-8") == text, f"{path.relative_to(index.ROOT)} is stale: run python -m bench.index"


def test_every_result_file_is_listed_with_a_date_and_a_title():
    text = (index.RESULTS / "README.md").read_text(encoding="utf-8")
    links = set(re.findall(r"\]\(([^)]+)\)", text))
    missing = [p.relative_to(index.RESULTS).as_posix() for p in index.result_files()
               if p.relative_to(index.RESULTS).as_posix() not in links]
    assert missing == []
    for folder in text.split("\n## ")[1:]:
        rows = [ln.split(" | ") for ln in folder.splitlines() if ln.startswith("| 20")]
        assert rows, folder.splitlines()[0]
        dates = [r[0].lstrip("| ") for r in rows]
        assert dates == sorted(dates), f"{folder.splitlines()[0]}: not in date order"
        assert all(re.fullmatch(r"\d{4}-\d\d-\d\d", d) for d in dates)
        assert all(len(r[2]) > 20 for r in rows)  # what it measured


def test_the_log_index_lists_every_entry_in_date_order_with_what_it_measured():
    text = (index.LOG / "README.md").read_text(encoding="utf-8")
    rows = [ln for ln in text.splitlines() if ln.startswith("| 20")]
    entries = sorted(p.name for p in index.LOG.glob("*.md") if p.name != "README.md")
    assert sorted(re.search(r"\]\(([^)]+)\)", r).group(1) for r in rows) == entries
    dates = [r[2:12] for r in rows]
    assert dates == sorted(dates)
    eval1 = next(r for r in rows if "2026-11-27-evaluation-01.md" in r)
    assert "(a) Image model per frame vs video model" in eval1 and "4 test room(s) of DATA/r160, 17 frames" in eval1


def test_titles_come_from_the_command_without_where_it_wrote():
    s = index.settings("python -m bench.pathtraced --data ~/data/outside320 --split test --tiers formula,residual --name x --out y.json")
    assert s == "data outside320, split test, tiers formula,residual"
    assert index.title("pathtraced", {"description": "Tier 1 on the v3 rooms", "command": "python -m bench.pathtraced"}) == \
        "Tier 1 on the v3 rooms"
    assert index.title("attention", {"info": {"channels": 64, "heads": 8}}).endswith("; channels 64, heads 8")


def test_a_result_without_a_date_is_named(tmp_path, monkeypatch):
    folder = tmp_path / "render"
    folder.mkdir()
    (folder / "render_new.json").write_text('{"command": "python -m bench.render"}')
    with pytest.raises(ValueError, match=r"bench/results/render/render_new\.json: no date"):
        index.rows_of(folder, {})
    assert index.rows_of(folder, {"render/render_new.json": "2026-12-05"})[0][0] == "2026-12-05"
