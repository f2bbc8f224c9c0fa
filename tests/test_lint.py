"""`ruff check .` (its rules in pyproject.toml, ruff pinned in the test extra) passes from the repository root, as a contributor runs it."""
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _ruff() -> str | None:
    beside = Path(sys.executable).with_name("ruff")
    return str(beside) if beside.is_file() else shutil.which("ruff")


def test_ruff_check_passes():
    ruff = _ruff()
    if ruff is None:
        pytest.fail("ruff is not installed: pip install -e '.[test]'")
    proc = subprocess.run([ruff, "check", "--no-cache", "."], cwd=ROOT, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stdout + proc.stderr


def test_no_machine_paths_in_tracked_files():
    """Checked-in files name DATA/, RUNS/, ~/ or repository-relative paths, never one machine's folders."""
    if not (ROOT / ".git").exists():
        pytest.skip("not a git checkout")
    pattern = "/" + "|/".join(("work/", "tmp/", "root/", "home/"))
    proc = subprocess.run(["git", "grep", "-nIE", pattern, "--", ".", ":!tests/test_lint.py"], cwd=ROOT, capture_output=True, text=True)
    assert proc.stdout == "", "machine paths in tracked files:\n" + proc.stdout[:3000]


def test_no_tracked_file_holds_merge_conflict_markers():
    """A merge left `<<<<<<< HEAD` ... `>>>>>>> branch` in docs/ARCHITECTURE.md once and nothing noticed."""
    files = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True).stdout.split()
    bad = []
    for name in files:
        path = ROOT / name
        if path.suffix not in (".py", ".md", ".toml", ".json", ".yaml", ".yml", ".txt", ".cfg", ".sh") or not path.is_file():
            continue
        for i, line in enumerate(path.read_text(encoding="utf-8", errors="replace").splitlines(), 1):
            if line.startswith(("<<<<<<< ", ">>>>>>> ")) or line == "=======" and path.suffix != ".md":
                bad.append(f"{name}:{i}")
    assert not bad, bad
