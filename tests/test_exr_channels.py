"""Reading only the channels a shot uses from an EXR (`read_image(path, channels=...)`, through OpenEXR's bindings):
the same planes as OpenImageIO's whole-file read, raw integer ids included, and the whole read wherever the
selective one cannot apply."""
from __future__ import annotations

import sys

import numpy as np
import pytest
from test_real_shots import write_blender_shot

from x2video.io import load_shot
from x2video.io.image import read_image, write_exr

pytest.importorskip("OpenEXR")


def _planes(rng, names, h=19, w=27):
    return {n: rng.uniform(-2, 50, (h, w)).astype(np.float32) for n in names}


@pytest.mark.parametrize("pixel_type", ["half", "float"])
def test_selected_channels_equal_the_whole_read(tmp_path, pixel_type):
    rng = np.random.default_rng(0)
    names = [f"ViewLayer.{p}.{c}" for p in ("Combined", "DiffDir", "GlossInd", "Normal", "Vector") for c in "RGB"]
    path = tmp_path / "f.exr"
    write_exr(path, _planes(rng, names), pixel_type, attributes={"x2video:irradiance_normalized": 1})
    whole = read_image(path)
    want = ["ViewLayer.Normal.G", "ViewLayer.DiffDir.R", "ViewLayer.DiffDir.R"]  # any order, repeats
    some = read_image(path, channels=want)
    assert set(some.planes) == {"ViewLayer.Normal.G", "ViewLayer.DiffDir.R"}  # only those: the fast path ran
    assert some.channel_names == whole.channel_names and some.format == whole.format == pixel_type
    assert some.attributes == whole.attributes and (some.width, some.height) == (27, 19)
    for n in some.planes:
        assert some.planes[n].dtype == np.float32 and np.array_equal(some.planes[n], whole.planes[n])
    assert some.all().shape == (19, 27, 2)  # what was read
    with pytest.raises(ValueError, match="'ViewLayer.Combined.R' was not read"):
        some.channel("ViewLayer.Combined.R")
    with pytest.raises(ValueError, match="no channel 'nope'"):
        some.channel("nope")


def test_raw_integer_ids_and_fallbacks(tmp_path, monkeypatch):
    ids = np.arange(19 * 27, dtype=np.uint32).reshape(19, 27) * 977
    write_exr(tmp_path / "ids.exr", {"ids.id": ids}, "uint")
    got = read_image(tmp_path / "ids.exr", channels=["ids.id"])
    assert got.planes["ids.id"].dtype == np.uint32 and np.array_equal(got.planes["ids.id"], ids)
    rng = np.random.default_rng(1)
    write_exr(tmp_path / "f.exr", _planes(rng, ["a.R", "a.G", "b.R"]), "float")
    # a channel the file lacks: the whole file through OpenImageIO, whose lookup then names what is missing
    assert set(read_image(tmp_path / "f.exr", channels=["a.R", "nope.R"]).planes) == {"a.R", "a.G", "b.R"}
    monkeypatch.setitem(sys.modules, "OpenEXR", None)  # the bindings not installed: the whole read, as before
    assert set(read_image(tmp_path / "f.exr", channels=["a.R"]).planes) == {"a.R", "a.G", "b.R"}


def test_a_blender_shot_reads_the_same_with_and_without_the_bindings(tmp_path, monkeypatch):
    write_blender_shot(tmp_path / "b", frames=3)
    fast = load_shot(tmp_path / "b")
    frames = [fast.frame(t) for t in range(3)]
    monkeypatch.setitem(sys.modules, "OpenEXR", None)
    slow = load_shot(tmp_path / "b")
    assert slow.info.irradiance_scale == fast.info.irradiance_scale  # the exposure scan reads irradiance alone
    for t in range(3):
        ref = slow.frame(t)
        assert set(ref) == set(frames[t])
        for k in ref:
            assert np.array_equal(ref[k], frames[t][k]), (t, k)


def test_noisy_irradiance_reads_the_sampled_light_passes(tmp_path):
    from x2video.train.residual_stage import noisy_irradiance

    rng = np.random.default_rng(2)
    planes = _planes(rng, [f"{p}.{c}" for p in ("NoisyDiffDir", "NoisyDiffInd", "DiffDir", "Combined") for c in "RGB"])
    write_exr(tmp_path / "f.exr", planes, "float")
    want = np.stack([planes[f"NoisyDiffDir.{c}"] + planes[f"NoisyDiffInd.{c}"] for c in "RGB"], -1).clip(0, None)
    np.testing.assert_array_equal(noisy_irradiance(tmp_path / "f.exr"), want)
    write_exr(tmp_path / "g.exr", {k: v for k, v in planes.items() if not k.startswith("NoisyDiffInd")}, "float")
    assert noisy_irradiance(tmp_path / "g.exr") is None
