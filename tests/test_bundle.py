"""The desktop bundle: `x2video-studio --selftest` from source (default suite), and the PyInstaller build with its
checks (packaging/build.sh) only when asked: `pytest -m bundle` (minutes, about 1 GB in a temporary folder)."""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _selftest(args, tmp_path, **env):
    e = {**os.environ, "QT_QPA_PLATFORM": "offscreen", "XDG_CACHE_HOME": str(tmp_path / "cache"), "XDG_CONFIG_HOME": str(tmp_path / "config"),
         **env}
    return subprocess.run([sys.executable, "-m", "x2video_app", "--selftest", *args], capture_output=True, text=True, env=e, timeout=900)


@pytest.mark.slow
def test_selftest_renders_two_frames_with_the_shipped_weights(tmp_path):
    pytest.importorskip("PySide6")
    from app_helpers import make_shot_dir

    from x2video.weights import shipped_weights

    if shipped_weights() is None:
        pytest.skip("no shipped weights in resources/")
    shot = make_shot_dir(tmp_path, frames=5, h=32, w=48)
    p = _selftest([str(shot)], tmp_path)
    assert p.returncode == 0, p.stdout[-3000:] + p.stderr[-3000:]
    line = [t for t in p.stdout.splitlines() if t.startswith("selftest:")]
    assert line and line[0].startswith("selftest: ok: ") and "rendered frames [0, 1] (diffusion" in line[0], p.stdout


def test_selftest_fails_and_says_why_without_weights(tmp_path):
    pytest.importorskip("PySide6")
    from app_helpers import make_shot_dir

    shot = make_shot_dir(tmp_path, frames=3, h=32, w=48)
    p = _selftest([str(shot)], tmp_path, X2VIDEO_WEIGHTS=str(tmp_path / "none"))
    assert p.returncode == 1, p.stdout + p.stderr
    assert "selftest: FAILED: the render did not start" in p.stdout


def test_desktop_entry_is_valid():
    validate = shutil.which("desktop-file-validate")
    if validate is None:
        pytest.skip("desktop-file-validate (Debian desktop-file-utils) is not installed")
    p = subprocess.run([validate, str(ROOT / "packaging" / "linux" / "x2video-studio.desktop")], capture_output=True, text=True)
    assert p.returncode == 0 and not p.stdout.strip(), p.stdout + p.stderr


@pytest.mark.bundle
@pytest.mark.timeout(5400)
def test_bundle_builds_and_passes_its_selftest(tmp_path):
    """packaging/build.sh: PyInstaller one-folder build, then the editor's --selftest and `x2video --help` in a bare
    environment (no venv on PATH, no PYTHONPATH); BUILD.json records size, build time and the selftest's time."""
    p = subprocess.run(["bash", str(ROOT / "packaging" / "build.sh"), "--dist", str(tmp_path)], cwd=ROOT, capture_output=True, text=True,
                       env={**os.environ, "PYTHON": sys.executable}, timeout=5300)
    assert p.returncode == 0, p.stdout[-5000:] + p.stderr[-5000:]
    out = tmp_path / "x2video-studio"
    build = json.loads((out / "BUILD.json").read_text())
    assert build["selftest_ms"] > 0 and build["size_bytes"] > 100e6
    for name in ("x2video-studio", "x2video", "install.sh", "share/x2video-studio.desktop", "share/x2video-studio.svg"):
        assert (out / name).is_file(), name
    assert list(out.rglob("x2video-tiny/config.json")) and list(out.rglob("libqoffscreen.so"))
    info = subprocess.run([str(out / "x2video"), "render", "--help"], capture_output=True, text=True, env={"PATH": "/usr/bin:/bin"}, timeout=600)
    assert info.returncode == 0 and "Seed of the initial noise" in info.stdout  # flag help from the bundled sources


def test_run_module_runs_a_module_through_the_editor_entry_point():
    """What a frozen bundle's editor does for `python -m MODULE` (it makes the demo shot that way): here `x2video --help`."""
    p = subprocess.run([sys.executable, "-m", "x2video_app", "--run-module", "x2video", "info", "--help"], capture_output=True, text=True,
                       timeout=300)
    assert p.returncode == 0, p.stderr
    assert p.stdout.startswith("usage: x2video info")
