"""Import contracts (pyproject.toml): the core never imports Qt or the app; the library never imports its command
line; the editor and the benches call the library, not the CLI; no import cycle inside a package of the core."""
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_import_contract_kept():
    lint = Path(sys.executable).with_name("lint-imports")
    proc = subprocess.run([str(lint)], cwd=ROOT, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "4 kept, 0 broken" in proc.stdout


def test_core_import_does_not_load_qt():
    code = "import sys, x2video, x2video.cli; x2video.cli.build_parser(); print(any(m.startswith(('PySide6', 'x2video_app')) for m in sys.modules))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip()
    assert out == "False"
