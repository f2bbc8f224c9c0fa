"""Flags generated from settings dataclasses (`x2video.fields`): one declaration per setting."""
from __future__ import annotations

import argparse

import pytest

from x2video.fields import add_field, add_fields, field_docs, from_args
from x2video.render.settings import RenderSettings
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


@pytest.fixture(scope="module")
def train_parser() -> argparse.ArgumentParser:
    from x2video.cli.train import register

    p = argparse.ArgumentParser()
    register(p.add_subparsers())
    return p


def test_train_stage_flags_come_from_their_dataclasses(train_parser):
    """No flags give each stage's dataclass defaults (with the stage's own steps, lr and EMA); today's flag names
    (--vae-layers, --pool-frames, --ema, --keep, --channel-drop, --ref-p, --shading-prior on|off, ...) still parse."""
    from x2video.cli import train as T
    from x2video.train.config import (
        AugmentConfig,
        CacheStageConfig,
        EncoderStageConfig,
        ImageStageConfig,
        LCMStageConfig,
        LoopConfig,
        VAEStageConfig,
        VideoStageConfig,
        WindowConfig,
    )

    req = {"vae": ["--data", "d", "--out", "o"], "image": ["--cache", "c", "--out", "o"], "video": ["--init", "i", "--cache", "c", "--out", "o"],
           "lcm": ["--teacher", "t", "--cache", "c", "--out", "o"], "encoder": ["--teacher", "t", "--data", "d", "--out", "o"],
           "cache": ["--data", "d", "--vae", "v", "--out", "o"]}
    parse = lambda stage, *extra: train_parser.parse_args(["train", stage, *req[stage], *extra])  # noqa: E731
    for stage, cls in (("vae", VAEStageConfig), ("image", ImageStageConfig), ("video", VideoStageConfig), ("lcm", LCMStageConfig),
                       ("encoder", EncoderStageConfig), ("cache", CacheStageConfig)):
        assert from_args(cls, parse(stage)) == cls(), stage
    assert from_args(CacheStageConfig, parse("cache", "--size", "160x112", "--batch", "4")) == CacheStageConfig(size=(160, 112), batch=4)
    assert T._loop_cfg(parse("lcm")) == LoopConfig(steps=1000, lr=1e-5, ema_decay=0.99)
    assert T._aug(parse("video")) == AugmentConfig() and T._window(parse("video")) == WindowConfig()

    a = parse("vae", "--vae-layers", "2", "--pool-frames", "3", "--eval-frames", "1", "--size", "32x24", "--vae-channels", "8,16",
              "--ema", "0.5", "--keep", "3", "--time-limit", "2", "--seed", "7")
    assert from_args(VAEStageConfig, a) == VAEStageConfig(layers_per_block=2, pool_frames_per_room=3, eval_frames_per_room=1, size=(32, 24),
                                                          vae_channels=(8, 16), seed=7)
    assert T._loop_cfg(a) == LoopConfig(steps=2000, lr=2e-4, ema_decay=0.5, keep_ckpts=3, time_limit_s=120.0, seed=7)
    a = parse("image", "--no-shading-prior", "--no-residual-prior", "--channel-drop", "0.1", "--prompt-drop", "0.2", "--prediction", "sample")
    assert from_args(ImageStageConfig, a, augment=T._aug(a)) == ImageStageConfig(
        shading_prior=False, residual_prior=False, prediction="sample", augment=AugmentConfig(channel_drop_p=0.1, prompt_drop_p=0.2))
    a = parse("video", "--shading-prior", "off", "--residual-prior", "on", "--ref-p", "0.2", "--train-only", "interp")
    assert from_args(VideoStageConfig, a, window=T._window(a)) == VideoStageConfig(
        shading_prior=False, residual_prior=True, train_only="interp", window=WindowConfig(ref_p_key=0.2, ref_p_interp=0.2))
    assert T._window(parse("lcm", "--ref-p", "0.2", "--ref-p-interp", "0.9")) == WindowConfig(ref_p_key=0.2, ref_p_interp=0.9)
    assert from_args(EncoderStageConfig, parse("encoder", "--pool-frames", "4", "--size", "64x48")) == \
        EncoderStageConfig(pool_frames_per_room=4, size=(64, 48))
    for bad in (["--shading-prior", "yes"], ["--train-only", "some"], ["--size", "3:4"]):
        with pytest.raises(SystemExit):
            parse("video" if bad[0] != "--size" else "encoder", *bad)


def test_a_three_state_bool_field_reads_on_off_and_goes_back_to_flags():
    from x2video.fields import to_flags
    from x2video.train.config import VideoStageConfig

    p = argparse.ArgumentParser()
    add_fields(p, VideoStageConfig, skip=("augment", "window"))
    assert p.parse_args([]).shading_prior is None and p.parse_args(["--shading-prior", "off"]).shading_prior is False
    stage = VideoStageConfig(shading_prior=True, residual_prior=False)
    flags = to_flags(VideoStageConfig, stage)
    assert flags == ["--shading-prior", "on", "--residual-prior", "off"]
    assert from_args(VideoStageConfig, p.parse_args(flags)) == stage
