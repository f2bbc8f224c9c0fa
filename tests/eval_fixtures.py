"""A tiny procedural held-out data set for the eval tests (one 64x48 room, rendered once per test module)."""
from __future__ import annotations

import warnings
from pathlib import Path

import pytest
import torch


def make_dataset(root: Path, frames: int = 9, size: tuple[int, int] = (64, 48), seed: int = 1) -> Path:
    """root/test/room_00001: one procedural room with rgb, ids, motion and captions."""
    from x2video.procedural.shotgen import write_procedural_shot

    write_procedural_shot(root / "test" / "room_00001", seed, frames, size[0], size[1], overwrite=True)
    return root


@pytest.fixture
def one_thread():
    """Single-threaded torch for the test (2 shared cores: extra threads only spin), restored after."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # the loader's NaN->0 notes
        yield
    torch.set_num_threads(before)
