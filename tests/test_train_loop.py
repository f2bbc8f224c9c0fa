"""The shared training loop: a resumed run continues exactly where a straight run would be; checkpoints, logs, time limit."""
from __future__ import annotations

import json

import pytest
import torch
from safetensors.torch import load_file, save_file

from x2video.train.loop import LoopConfig, latest_checkpoint, list_checkpoints, train


def _problem():
    torch.manual_seed(0)
    module = torch.nn.Sequential(torch.nn.Linear(4, 8), torch.nn.Tanh(), torch.nn.Linear(8, 1))
    g = torch.Generator().manual_seed(1)
    xs = torch.randn(64, 4, generator=g)
    ys = xs.sum(1, keepdim=True).sin()

    def batches(start):  # batch i depends only on the step: a resumed run sees what a straight run sees
        step = start
        while True:
            idx = torch.arange(step * 8, step * 8 + 8) % 64
            yield xs[idx], ys[idx]
            step += 1

    def loss_fn(batch, step):
        x, y = batch
        return torch.nn.functional.mse_loss(module(x), y), {"extra": 1.0}

    def save(m, d):
        d.mkdir(parents=True, exist_ok=True)
        save_file({k: v.contiguous() for k, v in m.state_dict().items()}, str(d / "w.safetensors"))

    return module, loss_fn, batches, save


def _run(out, steps, **kw):
    module, loss_fn, batches, save = _problem()
    cfg = LoopConfig(steps=steps, lr=1e-2, warmup=2, lr_half_every=3, ema_decay=0.9, ckpt_every=2, keep_ckpts=2, **kw)
    ck = train(module=module, loss_fn=loss_fn, batches=batches, save_fn=save, out_dir=out, cfg=cfg,
               stage_config={"stage": "test", "sizes": (4, 8)}, batch_size=8)
    return module, ck


def test_resume_continues_exactly(tmp_path):
    straight, ck_a = _run(tmp_path / "a", 6)
    _run(tmp_path / "b", 4)
    resumed, ck_b = _run(tmp_path / "b", 6)  # the tuple in stage_config must not block the resume
    for p, q in zip(straight.parameters(), resumed.parameters()):
        torch.testing.assert_close(p, q, rtol=1e-5, atol=1e-6)
    # the saved (EMA) inference weights agree too, and differ from the raw weights
    wa, wb = load_file(str(ck_a / "model" / "w.safetensors")), load_file(str(ck_b / "model" / "w.safetensors"))
    for k in wa:
        torch.testing.assert_close(wa[k], wb[k], rtol=1e-5, atol=1e-6)
    assert not torch.allclose(wa["0.weight"], straight[0].weight.detach())
    la = json.loads((tmp_path / "a" / "log.json").read_text())
    lb = json.loads((tmp_path / "b" / "log.json").read_text())
    assert [h["step"] for h in lb] == [1, 2, 3, 4, 5, 6]
    assert [round(h["loss"], 6) for h in la] == [round(h["loss"], 6) for h in lb]
    assert [h["lr"] for h in la] == [h["lr"] for h in lb]
    assert [c.name for c in list_checkpoints(tmp_path / "b")] == ["step-000000004", "step-000000006"]
    s = json.loads((tmp_path / "b" / "summary.json").read_text())
    assert s["first_step"] == 4 and s["steps_run"] == 2


def test_resume_refuses_other_stage_config(tmp_path):
    _run(tmp_path, 2)
    module, loss_fn, batches, save = _problem()
    with pytest.raises(ValueError, match="another stage config"):
        train(module=module, loss_fn=loss_fn, batches=batches, save_fn=save, out_dir=tmp_path, cfg=LoopConfig(steps=3),
              stage_config={"stage": "other"}, batch_size=8)


def test_time_limit_stops_with_a_checkpoint_and_timing_is_logged(tmp_path):
    module, loss_fn, batches, save = _problem()
    seen = []
    ck = train(module=module, loss_fn=loss_fn, batches=batches, save_fn=save, out_dir=tmp_path,
               cfg=LoopConfig(steps=10_000, time_limit_s=1e-9, ckpt_every=10_000), stage_config={}, batch_size=8, on_step=seen.append)
    assert ck == latest_checkpoint(tmp_path) and ck.name == "step-000000001"
    assert json.loads((ck / "state.json").read_text())["step"] == 1
    seen.clear()
    train(module=module, loss_fn=loss_fn, batches=batches, save_fn=save, out_dir=tmp_path / "t",
          cfg=LoopConfig(steps=4), stage_config={}, batch_size=8, on_step=seen.append)
    timed = [s for s in seen if s.timing is not None]
    assert len(timed) == 1 and set(timed[0].timing) >= {"data", "forward", "backward"} and timed[0].timing["steps"] == 3


def test_nan_loss_stops_with_a_clear_error(tmp_path):
    module, _, batches, save = _problem()
    with pytest.raises(FloatingPointError, match="step 0"):
        train(module=module, loss_fn=lambda b, s: (module(b[0]).sum() * float("nan"), {}), batches=batches, save_fn=save,
              out_dir=tmp_path, cfg=LoopConfig(steps=2), stage_config={}, batch_size=8)
