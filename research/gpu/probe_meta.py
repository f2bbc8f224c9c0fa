"""A probe cache from the test split alone: its rooms become the train split (the real train rooms
are marked unused), so the full training path runs on the GPU before the train split arrives."""
import json, sys
from pathlib import Path
p = Path(sys.argv[1]) / "meta.json"
m = json.loads(p.read_text())
for r in m["rooms"]:
    r["split"] = {"test": "train", "train": "unused"}[r["split"]]
p.write_text(json.dumps(m))
