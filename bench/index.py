"""Writes bench/results/README.md: one table per bench folder, one row per result (what, the command that
reproduces it, the commit it ran at).

    python -m bench.index
"""
from __future__ import annotations

import json
import sys

from bench.common import RESULTS


def _row(path) -> str:
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as e:
        return f"| [{path.name}]({path.parent.name}/{path.name}) | unreadable: {e} | | |"
    machine = doc.get("machine") or next((v for v in doc.get("runs", {}).values() if isinstance(v, dict)), {})
    commit = str(machine.get("git_commit") or "")[:7] if isinstance(machine, dict) else ""
    command = doc.get("command") or ""
    what = doc.get("format") or ", ".join(sorted(doc)[:4])
    return f"| [{path.name}]({path.parent.name}/{path.name}) | {what} | {'`' + command + '`' if command else ''} | {commit} |"


def index() -> str:
    lines = ["# Benchmark results", "",
             "One folder per bench (`python -m bench.NAME`, NAME the folder), written by the bench's `--out` (default",
             "bench/results/NAME/NAME.json). Paths inside are repository-relative or placeholders (DATA/ a data set",
             "from `x2video dataset make`, RUNS/ a training run); the command reproduces the file. Regenerate this",
             "index with `python -m bench.index`. The editor's speed-vs-accuracy chart plots every row of these",
             "files that has seconds per frame and PSNR.", ""]
    for folder in sorted(p for p in RESULTS.iterdir() if p.is_dir()):
        files = sorted(folder.glob("*.json"))
        lines += [f"## {folder.name}", "", "| file | what | command | commit |", "|---|---|---|---|"]
        lines += [_row(f) for f in files] + [""]
    return "\n".join(lines)


def main() -> int:
    from x2video.io.atomic import write_text_atomic

    write_text_atomic(RESULTS / "README.md", index())
    print(f"wrote {RESULTS / 'README.md'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
