"""Writers: round trips within half-float / PNG precision, MP4 decodes back, and writes are atomic."""
import av
import numpy as np
import pytest

from x2video.io import load_shot, write_shot_folder
from x2video.io.writers import MP4Writer, write_mp4, write_multilayer, write_png_sequence
from x2video.shot import ArrayShot, CameraPose

T, H, W = 4, 10, 14


@pytest.fixture
def shot():
    rng = np.random.default_rng(5)
    n = rng.normal(size=(T, H, W, 3))
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    s = ArrayShot({
        "albedo": rng.random((T, H, W, 3)), "normal": n, "roughness": rng.random((T, H, W, 1)),
        "metallic": rng.random((T, H, W, 1)), "irradiance": rng.random((T, H, W, 3)) * 6,
        "ids": rng.integers(0, 4000, (T, H, W)), "rgb": rng.random((T, H, W, 3)) * 3, "depth": rng.random((T, H, W)) * 9,
    }, fps=12.0, caption="c")
    s.info.poses = [CameraPose(np.eye(4) * (t + 1)) for t in range(T)]
    return s


def _half_close(a, b):
    np.testing.assert_allclose(a, b, rtol=2**-10, atol=2**-14)


def test_exr_sequence_and_multilayer_round_trip(shot, tmp_path):
    for name, write in (("seq", write_shot_folder), ("ml", write_multilayer)):
        write(shot, tmp_path / name)
        back = load_shot(tmp_path / name)
        assert back.info.channels == shot.info.channels and back.info.fps == 12.0 and back.info.irradiance_scale == 1.0
        np.testing.assert_allclose(back.info.poses[3].cam_to_world, np.eye(4) * 4)
        for t in range(T):
            for c in ("albedo", "normal", "roughness", "metallic", "irradiance", "rgb"):
                _half_close(back.channel(c, t), shot.channel(c, t))
            assert np.array_equal(back.channel("ids", t), shot.channel("ids", t))
            assert np.array_equal(back.channel("depth", t), shot.channel("depth", t))


def test_png_round_trip(shot, tmp_path):
    seen = []
    write_png_sequence(shot, tmp_path / "png", progress=seen.append)
    assert seen == list(range(T))
    back = load_shot(tmp_path / "png")
    assert set(back.channels) == set(shot.channels) - {"depth"}
    for t in range(T):
        np.testing.assert_allclose(back.channel("albedo", t), shot.channel("albedo", t), atol=1e-4)
        np.testing.assert_allclose(back.channel("normal", t), shot.channel("normal", t), atol=1e-4)
        np.testing.assert_allclose(back.channel("roughness", t), shot.channel("roughness", t), atol=1e-4)
        assert np.array_equal(back.channel("ids", t), shot.channel("ids", t))
        np.testing.assert_allclose(back.channel("irradiance", t), np.clip(shot.channel("irradiance", t), 0, 1), atol=1e-4)


def test_mp4(shot, tmp_path):
    write_mp4(shot, tmp_path / "a.mp4", channel="rgb", fps=24)
    with av.open(str(tmp_path / "a.mp4")) as c:
        st = c.streams.video[0]
        assert st.codec_context.name == "h264" and st.codec_context.pix_fmt == "yuv420p"
        assert float(st.average_rate) == 24
        frames = [f.to_ndarray(format="rgb24") for f in c.decode(st)]
    assert len(frames) == T and frames[0].shape == (H, W, 3)
    # odd sizes are padded to even
    odd = ArrayShot({"albedo": np.full((2, 7, 9, 3), 0.5)})
    write_mp4(odd, tmp_path / "odd.mp4", channel="albedo")
    with av.open(str(tmp_path / "odd.mp4")) as c:
        f = next(c.decode(video=0))
        assert (f.height, f.width) == (8, 10)
        assert abs(int(f.to_ndarray(format="rgb24")[3, 3, 1]) - 188) <= 3  # sRGB(0.5) = 188
    with pytest.raises(ValueError, match="no channel 'rgb'"):
        write_mp4(odd, tmp_path / "x.mp4")


def test_atomic_exports(shot, tmp_path):
    def crash(t):
        if t == 2:
            raise RuntimeError("crash mid-export")

    with pytest.raises(RuntimeError):
        write_mp4(shot, tmp_path / "a.mp4", progress=crash)
    with pytest.raises(RuntimeError):
        with MP4Writer(tmp_path / "b.mp4") as w:
            w.write(np.zeros((H, W, 3), np.float32))
            raise RuntimeError("crash")
    with pytest.raises(RuntimeError):
        write_shot_folder(shot, tmp_path / "seq", progress=crash)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["seq"]
    assert not (tmp_path / "seq" / "shot.json").exists()  # an unfinished folder has no shot.json
    assert not [p for p in tmp_path.rglob("*") if p.name.startswith(".")]  # no temp files left
