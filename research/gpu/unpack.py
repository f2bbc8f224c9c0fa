"""Rebuild a latent cache folder (train/test.safetensors, text, meta.json, model/) from packed parts."""
import json, lzma, shutil, sys
from pathlib import Path
import numpy as np
import torch
from safetensors.torch import save_file

def unpack(stash: Path, split: str) -> dict:
    meta = json.loads((stash / f"{split}.meta.json").read_text())
    out = {}
    def raw(k):
        m = meta[k]
        if m["kind"] == "raw":
            return torch.from_numpy(np.frombuffer(lzma.decompress((stash / f"{split}.{k}.z").read_bytes()), dtype=m["dtype"]).reshape(m["shape"]).copy())
        q = np.frombuffer(lzma.decompress((stash / f"{split}.{k}.z").read_bytes()), dtype=np.uint8).reshape(m["shape"])
        lo = torch.tensor(m["lo"]).view(1, -1, 1, 1); hi = torch.tensor(m["hi"]).view(1, -1, 1, 1)
        return torch.from_numpy(q.astype(np.float32)) / 255 * (hi - lo) + lo
    full = "tier1_111" if "tier1_111" in meta else "shading_11"
    base = raw(full)
    for k, m in meta.items():
        v = base if k == full else raw(k)
        if m.get("base"):
            v = v + base
        out[k] = v.half() if m["kind"] == "q8" else v
    return out

if __name__ == "__main__":
    stash, cache = Path(sys.argv[1]), Path(sys.argv[2])
    cache.mkdir(parents=True, exist_ok=True)
    for split in sys.argv[3:]:
        save_file(unpack(stash, split), str(cache / f"{split}.safetensors"))
    (cache / "text.safetensors").write_bytes(lzma.decompress((stash / "text.safetensors.xz").read_bytes()))
    shutil.copy(stash / "meta.json", cache / "meta.json")
    shutil.copytree(stash / "model", cache / "model", dirs_exist_ok=True)
    print("cache rebuilt:", cache, sorted(p.name for p in cache.iterdir()), flush=True)
