"""Flags generated from settings dataclasses (`x2video.cli.fields`): one declaration per setting."""
from __future__ import annotations

import argparse

import pytest

from x2video.cli.fields import add_field, add_fields, field_docs, from_args
from x2video.sampling.events import RenderSettings
from x2video.train.config import AugmentConfig


def _parser(cls=RenderSettings) -> argparse.ArgumentParser:
    p = argparse.ArgumentParser()
    add_fields(p, cls)
    return p


def test_no_flags_give_the_dataclass_defaults_and_every_field_has_help():
    assert from_args(RenderSettings, _parser().parse_args([])) == RenderSettings()
    docs = field_docs(RenderSettings)
    assert set(docs) == {f for f in RenderSettings.__dataclass_fields__} and all(docs.values())
    help_text = _parser().format_help()
    assert "--noise-shared" in help_text and "--no-seams" in help_text and "{ddim,lcm}" in help_text


def test_flags_parse_to_typed_settings():
    a = _parser().parse_args(["--sampler", "lcm", "--steps", "2", "--frames", "2:5", "--no-seams", "--max-levels", "2",
                              "--noise", "window", "--ref-dc", "0.5", "--preset", "fast", "--no-detail"])
    s = from_args(RenderSettings, a)
    assert (s.sampler, s.steps, s.frames, s.seams, s.max_levels, s.noise, s.ref_dc, s.preset, s.detail) == \
        ("lcm", 2, (2, 5), False, 2, "window", 0.5, "fast", False)
    with pytest.raises(SystemExit):
        _parser().parse_args(["--sampler", "euler"])
    with pytest.raises(SystemExit):
        _parser().parse_args(["--frames", "3"])


def test_a_flag_named_unlike_its_field_takes_its_default_and_help():
    p = argparse.ArgumentParser()
    add_field(p, "--channel-drop", AugmentConfig, "channel_drop_p")
    assert p.parse_args([]).channel_drop == AugmentConfig.channel_drop_p
    assert "Probability of dropping each intrinsic channel" in p.format_help()
