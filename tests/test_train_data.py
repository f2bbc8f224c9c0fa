"""Training data helpers: data set discovery and resizing channels to the training size."""
from __future__ import annotations

import argparse

import numpy as np
import pytest

from x2video.cli.args import size_arg
from x2video.fields import parse_size
from x2video.io.dataset import shot_dirs
from x2video.train.data import resize_channel


def test_resize_channel_keeps_each_channel_convention():
    rng = np.random.default_rng(0)
    n = rng.normal(size=(24, 32, 3)).astype(np.float32)
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    small = resize_channel("normal", n, (16, 12))
    assert small.shape == (12, 16, 3)
    np.testing.assert_allclose(np.linalg.norm(small, axis=-1)[np.linalg.norm(small, axis=-1) > 0], 1.0, atol=1e-5)
    ids = rng.integers(0, 5, size=(24, 32, 1)).astype(np.int32)
    r = resize_channel("ids", ids, (16, 12))
    assert r.shape == (12, 16, 1) and set(np.unique(r)) <= set(np.unique(ids))  # nearest: no blended ids
    a = np.full((24, 32, 3), 0.25, np.float32)
    np.testing.assert_allclose(resize_channel("albedo", a, (16, 12)), 0.25, atol=1e-6)
    assert resize_channel("albedo", a, (32, 24)) is a


def test_parse_size_and_dataset_errors(tmp_path):
    assert parse_size("160x112") == (160, 112)
    with pytest.raises(ValueError, match="WIDTHxHEIGHT"):
        parse_size("160")
    # the one argparse type every command and bench takes --size with, and the data set's minimum
    assert size_arg("96X64") == (96, 64)
    with pytest.raises(argparse.ArgumentTypeError, match="'96x-4' must be positive"):
        size_arg("96x-4")
    with pytest.raises(ValueError, match="at least 8"):
        parse_size("320x4", 8)
    with pytest.raises(FileNotFoundError):
        shot_dirs(tmp_path / "missing", "train")
    (tmp_path / "train" / "room_a").mkdir(parents=True)
    (tmp_path / "train" / "room_a" / "shot.json").write_text("{}")
    (tmp_path / "train" / "not_a_shot").mkdir()
    assert [p.name for p in shot_dirs(tmp_path, "train")] == ["room_a"]
    assert shot_dirs(tmp_path, "test") == []
    with pytest.raises(ValueError, match="one shot folder"):
        shot_dirs(tmp_path / "train" / "room_a", "train")
