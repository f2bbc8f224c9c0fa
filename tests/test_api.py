"""The public API (`import x2video`): lazy names, the shipped weights found without the repository layout."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest
import tomllib

ROOT = Path(__file__).resolve().parents[1]


def test_import_is_cheap_and_exports_the_api():
    code = ("import sys, x2video; heavy = [m for m in ('torch', 'diffusers', 'PySide6') if m in sys.modules]; "
            "print(heavy, sorted(x2video.__all__))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.startswith("[]")
    for name in ("load_shot", "load_model", "Renderer", "RenderSettings", "Edits", "FrameSink"):
        assert f"'{name}'" in out
    import x2video

    assert x2video.RenderSettings().steps == 20 and x2video.Edits().global_prompt == ""
    with pytest.raises(AttributeError):
        x2video.not_a_name  # noqa: B018


def test_shipped_weights_found_as_package_data_or_from_the_environment(tmp_path, monkeypatch):
    from x2video import weights

    monkeypatch.delenv(weights.ENV, raising=False)
    found = weights.shipped_weights()
    assert found is not None and weights.is_checkpoint(found) and found.name == weights.NAME
    # the first place looked is the package's own resources/ (what a wheel holds), not the repository's
    from importlib import resources

    assert Path(str(resources.files("x2video") / "resources" / weights.NAME)) == found
    monkeypatch.setenv(weights.ENV, str(tmp_path))
    assert weights.shipped_weights() == tmp_path
    with pytest.raises(FileNotFoundError, match="not a model checkpoint"):
        weights.load_model()


def test_the_wheel_ships_every_weights_file():
    """pyproject's package-data globs cover every file of the shipped model (a wheel built with
    `pip wheel . --no-deps` then holds them under x2video/resources/)."""
    import fnmatch

    globs = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["package-data"]["x2video"]
    package = ROOT / "core" / "x2video"
    files = [p.relative_to(package).as_posix() for p in (package / "resources").rglob("*") if p.is_file()]
    assert any(f.endswith("unet.safetensors") for f in files)
    missing = [f for f in files if not any(fnmatch.fnmatch(f, g) for g in globs)]
    assert missing == []


def test_paths_recorded_portably(monkeypatch, tmp_path):
    from x2video.io.paths import portable_path, scrub_paths

    monkeypatch.chdir(tmp_path)
    assert portable_path(tmp_path / "bench" / "r.json") == "bench/r.json"  # inside the current folder: relative
    assert portable_path("runs/video") == "runs/video"
    assert portable_path("/mnt/data/r160") == "DATA/r160" and portable_path("/srv/runs/a/b") == "RUNS/a/b"
    assert portable_path(Path.home() / "x") == "~/x"
    text = "x2video eval --data /mnt/data/r160 --out /mnt/results/e1; see https://example.org/a/b; 1.2 s/frame; PATH=/usr/bin"
    assert scrub_paths(text) == "x2video eval --data DATA/r160 --out RESULTS/e1; see https://example.org/a/b; 1.2 s/frame; PATH=/usr/bin"
