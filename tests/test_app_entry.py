"""The editor's entry point in a subprocess: `python -m x2video_app` with no path opens the demo shot
(generated into an empty cache), and with a bad path it says what is wrong and still exits cleanly."""
import os
import subprocess
import sys

import pytest

pytest.importorskip("PySide6")


def _run(args, tmp_path, **env):
    e = {**os.environ, "QT_QPA_PLATFORM": "offscreen", "XDG_CACHE_HOME": str(tmp_path / "cache"), "XDG_CONFIG_HOME": str(tmp_path / "config"),
         "X2VIDEO_WEIGHTS": str(tmp_path / "none"), **env}
    return subprocess.run([sys.executable, "-m", "x2video_app", "--smoke-test", *args], capture_output=True, text=True, env=e, timeout=600)


def test_no_argument_opens_the_generated_demo_shot(tmp_path):
    demo = tmp_path / "demo"
    p = _run([], tmp_path, X2VIDEO_DEMO_DIR=str(demo))
    assert p.returncode == 0, p.stdout + p.stderr
    assert "smoke-test: opened=True frames=33 errors=[]" in p.stdout
    assert any((d / "shot.json").is_file() for d in demo.iterdir())


def test_bad_path_reports_and_exits(tmp_path):
    p = _run([str(tmp_path / "nope")], tmp_path)
    assert p.returncode == 1
    assert "opened=False" in p.stdout and "nope" in p.stdout
