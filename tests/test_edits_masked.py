"""bench.edits' masked kind (issue 52): the edit it builds on a room's albedo pair (A|M|R masked out, a local prompt naming
the colour), and the two ways a generated frame goes over the shot's base (`x2video.base.stage.GeneratedOver`): each
keeps every pixel outside the edit's reach bit for bit; "difference" is the base plus the frame minus tier 1's frame of
the unedited channels."""
from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from sampling_fake import FakeModel

from x2video.base.difference import SPILL_MARGIN, grow
from x2video.conditioning.edited import apply_edits, frame_conditioning
from x2video.edits.model import Edits
from x2video.edits.ops import MaskOut
from x2video.model import residual as R
from x2video.render.events import FramesReady
from x2video.render.renderer import Renderer
from x2video.render.settings import RenderSettings
from x2video.shot import ArrayShot
from x2video.tiers.residual import residual_frames

pytestmark = pytest.mark.usefixtures("torch_one_thread")

H, W, T, OBJ = 32, 48, 3, 7
BOX = (slice(10, 22), slice(16, 32))  # the object's pixels (id OBJ)


def room_with_ids(scale: float = 1.0) -> ArrayShot:
    """Five channels, an id channel with one object, and a path-traced rgb holding light the channels lack."""
    rng = np.random.default_rng(5)
    albedo = rng.uniform(0.1, 0.9, (T, H, W, 3)).astype(np.float32)
    irr = np.broadcast_to(np.linspace(0.5, 2.0, W, dtype=np.float32)[None, None, :, None], (T, H, W, 3)).copy()
    normal = np.zeros((T, H, W, 3), np.float32)
    normal[..., 2] = 1
    ids = np.zeros((T, H, W, 1), np.float32)
    ids[:, BOX[0], BOX[1]] = OBJ
    rgb = albedo * irr
    rgb[:, 2:8, 2:12] += 3.0  # a window: light the channels do not hold
    return ArrayShot({"albedo": albedo, "irradiance": irr * scale, "normal": normal, "ids": ids, "rgb": rgb,
                      "roughness": np.full((T, H, W, 1), 0.6, np.float32), "metallic": np.full((T, H, W, 1), 0.2, np.float32)},
                     irradiance_scale=scale)


def with_net() -> FakeModel:
    m = FakeModel()
    torch.manual_seed(0)
    m.residual_net = R.ResidualNet(R.ResidualConfig(widths=(8, 16))).eval()
    torch.nn.init.normal_(m.residual_net.out.weight, std=0.1)  # not the zero init: tier 1 must differ from the formula
    return m


def test_the_masked_kind_masks_out_the_objects_amr_and_names_its_new_colour_in_a_local_prompt(tmp_path):
    from bench.edits import edit_pair
    from bench.edits_masked import AMR, colour_name, masked_pair

    assert masked_pair(tmp_path) is None  # no albedo pair in the room
    (tmp_path / "after_albedo").mkdir()
    doc = {"kind": "albedo", "target": {"id": OBJ, "caption": "a black plastic cabinet", "category": "cabinet"},
           "look": {"kind": "albedo", "id": OBJ, "color": [0.85, 0.55, 0.02]}, "edits": {}, "cycles": {"seconds_per_frame": 4.0}}
    (tmp_path / "after_albedo" / "edits.json").write_text(json.dumps(doc))
    shot_dir, truth_dir, rec = edit_pair(tmp_path, "masked")
    assert (shot_dir, truth_dir) == (tmp_path / "before", tmp_path / "after_albedo")  # the albedo pair: Cycles' recolour is the truth
    assert rec["kind"] == "masked" and rec["look"]["prompt"] == "a yellow cabinet" and rec["cycles"]["seconds_per_frame"] == 4.0

    edits = Edits.from_dict(rec["edits"])
    (name,) = edits.masks
    assert edits.masks[name].ids == [OBJ] and edits.masked_out(name)
    (op,) = edits.ops
    assert isinstance(op, MaskOut) and sorted(op.channels) == sorted(AMR) == ["albedo", "metallic", "roughness"]
    assert edits.local_prompts == {name: "a yellow cabinet"} and edits.prompts().local == ["a yellow cabinet"]

    shot = room_with_ids()
    c = apply_edits(shot, edits, 1)
    obj = np.zeros((H, W), bool)
    obj[BOX] = True
    for ch in AMR:
        assert not c.channels[ch][obj].any() and np.array_equal(c.channels[ch][~obj], shot.channel(ch, 1)[~obj])
    assert np.array_equal(c.channels["irradiance"], shot.channel("irradiance", 1))  # the light is kept
    assert np.array_equal(c.amr_mask > 0.5, obj) and c.local_masks.shape == (1, H, W) and np.array_equal(c.local_masks[0] > 0.5, obj)
    with pytest.raises(ValueError, match="COLOURS"):
        colour_name([0.5, 0.5, 0.5])


@pytest.mark.parametrize("scale", [1.0, 0.37])
def test_a_generated_frame_replaces_or_adds_over_the_base_inside_the_reach_only(scale):
    from bench.edits_masked import masked_edits

    shot = room_with_ids(scale)
    edits = Edits.from_dict(masked_edits(OBJ, "a yellow cabinet"))
    model = with_net()
    settings = RenderSettings(preset="fast", window=3)
    obj = np.zeros((H, W), bool)
    obj[BOX] = True
    reach = grow(obj, SPILL_MARGIN)
    made = {}
    for how in ("replace", "difference"):
        renderer = Renderer(model)
        events: list = []
        renderer.render(shot, edits, settings, events.append, generated=how)
        assert renderer.last_tier.tier == "diffusion" and renderer.last_tier.regions  # generated inside, tier 1 around
        frames = {t: f for e in events if isinstance(e, FramesReady) for t, f in e.frames.items()}
        assert sorted(frames) == list(range(T))
        for t, f in frames.items():
            base = shot.channel("rgb", t).astype(np.float64) * scale
            assert np.array_equal(f[~reach], base[~reach]), f"{how}: frame {t} changed a pixel outside the edit's reach"
            assert not np.allclose(f[obj], base[obj]), f"{how}: frame {t} left the masked object as it was"
        made[how] = frames
    # on the object (what the edit changed) the weight is 1: replace is the generated frame G, difference base + G - R, so
    # the two differ by base - R wherever it is not clipped at 0 (R: tier 1's frame of the frame's unedited channels)
    original = frame_conditioning(shot, None)
    for t in range(T):
        r = residual_frames(model.residual_net, [original(t)], guess_unseen=settings.guess_unseen, max_pixels=settings.residual_pixels,
                            plausible=True)[0].astype(np.float64)
        base = shot.channel("rgb", t).astype(np.float64) * scale
        rep, dif = made["replace"][t], made["difference"][t]
        ok = obj & (dif > 0).all(-1)
        assert ok.sum() > obj.sum() // 2
        np.testing.assert_allclose(dif[ok], (rep + base - r)[ok], rtol=1e-5, atol=1e-5)


def test_an_unknown_way_over_the_base_is_an_error_naming_it():
    from bench.edits_masked import masked_edits

    shot = room_with_ids()
    with pytest.raises(ValueError, match="generated: 'sum'"):
        Renderer(with_net()).render(shot, Edits.from_dict(masked_edits(OBJ, "a red cabinet")), RenderSettings(preset="fast", window=3),
                                    generated="sum")


def test_the_seam_statistic_sees_a_step_at_the_reachs_edge_and_not_a_smooth_ramp():
    from bench.edits_masked import rings, seam

    reach = np.zeros((40, 60), bool)
    reach[10:30, 15:45] = True
    ring = rings(reach)
    assert ring["edge"].any() and ring["inside"].any() and ring["outside"].any()
    assert not (ring["edge"] & ring["inside"]).any() and not (ring["edge"] & ring["outside"]).any()
    ramp = np.broadcast_to(np.linspace(0, 1, 60, dtype=np.float32)[None, :, None], (40, 60, 3)).copy()
    step = ramp + 0.3 * reach[..., None]
    smooth, stepped = seam([ramp], [ring])["jump"], seam([step], [ring])["jump"]
    assert smooth == pytest.approx(1.0, abs=0.05) and stepped > 3 * smooth
    assert rings(np.ones((4, 4), bool))["edge"].sum() == 0  # a reach that is the whole frame has no edge
