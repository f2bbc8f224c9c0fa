"""Ref-Keyframe plans (`plan_keyframed`): given keyframes are read, never made; every other frame is made once."""
from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from x2video.sampling.planner import Window, num_levels, plan_keyframed


def check_keyframed(plan: list[Window], length: int, window: int, keys: list[int], max_levels: int | None = None) -> None:
    produced = set(keys)
    counts = [0] * length
    for i, w in enumerate(plan):
        assert 2 <= len(w.frames) <= window, (i, w)
        assert set(w.refs) <= produced, f"window {i} reads {set(w.refs) - produced} before they exist"
        assert not set(w.generate) & produced, f"window {i} makes {set(w.generate) & produced} again (or a keyframe)"
        assert set(w.frames) == set(w.generate) | set(w.refs) and not w.user_ref, w
        for f in w.generate:
            counts[f] += 1
        produced |= set(w.generate)
        if w.mode == "interp":
            assert w.refs == (w.frames[0], w.frames[-1]) and w.ref_positions == (0, len(w.frames) - 1)
            stride = (window - 1) ** (w.level - 1)
            steps = [b - a for a, b in zip(w.frames, w.frames[1:])]
            assert all(s == stride for s in steps[:-1]) and 0 < steps[-1] <= stride, w
        else:
            assert w.refs == (w.frames[0],) and w.ref_positions == (0,), w
    assert counts == [0 if t in keys else 1 for t in range(length)], "keyframes never made, every other frame once"
    levels = [w.level for w in plan]
    assert levels == sorted(levels, reverse=True)
    if window > 2 and max_levels is None:
        # between two adjacent keyframes more than one frame apart, the widest window's ends are those keyframes
        for a, b in zip(keys, keys[1:]):
            if b - a > 1:
                inside = [w for w in plan if a <= min(w.frames) and max(w.frames) <= b]
                assert inside[0].mode == "interp" and (inside[0].frames[0], inside[0].frames[-1]) == (a, b), (a, b, inside[0])


@settings(max_examples=400, deadline=None)
@given(st.integers(1, 200), st.integers(2, 9), st.data())
def test_keyframed_plans_make_every_frame_but_the_keyframes_once(length: int, window: int, data: st.DataObject) -> None:
    keys = sorted(data.draw(st.sets(st.integers(0, length - 1), min_size=1, max_size=12)))
    check_keyframed(plan_keyframed(length, window, keys), length, window, keys)
    check_keyframed(plan_keyframed(length, window, keys, "sequential"), length, window, keys, max_levels=1)
    cap = data.draw(st.integers(1, 4))
    capped = plan_keyframed(length, window, keys, max_levels=cap)
    check_keyframed(capped, length, window, keys, max_levels=cap)
    assert max((w.level for w in capped), default=1) <= cap


def test_every_8_of_17_frames_is_interpolation_between_keyframes() -> None:
    """Keyframes 0, 8, 16 at N = 5: level 2 (stride 4) between each pair, then level 1; nothing in keyframe mode."""
    plan = plan_keyframed(17, 5, [0, 8, 16])
    assert plan[:2] == [Window((0, 4, 8), (4,), (0, 8), "interp", 2), Window((8, 12, 16), (12,), (8, 16), "interp", 2)]
    assert [w.frames for w in plan[2:]] == [(0, 1, 2, 3, 4), (4, 5, 6, 7, 8), (8, 9, 10, 11, 12), (12, 13, 14, 15, 16)]
    assert {w.level for w in plan[2:]} == {1}


def test_the_papers_ref_keyframe_plan_is_the_recursive_plan_without_its_keyframe_window() -> None:
    """Keyframes 16 apart over 65 frames: exactly `plan_recursive`'s interpolation windows (paper Fig. recursive_sample)."""
    from x2video.sampling.planner import plan_recursive

    keyed = plan_keyframed(65, 5, range(0, 65, 16))
    assert keyed == [w for w in plan_recursive(65, 5) if w.mode == "interp"]
    assert num_levels(64, 5) == 3 and {w.level for w in keyed} == {2, 1}


def test_frames_outside_the_keyframes_run_in_keyframe_mode_from_them() -> None:
    plan = plan_keyframed(12, 5, [4, 8])
    key = [w for w in plan if w.mode == "key"]
    assert [(w.frames[0], w.refs) for w in key] == [(8, (8,)), (4, (4,))]  # after the last, then back from the first
    assert key[1].frames == (4, 0)  # backwards in time
    single = plan_keyframed(9, 5, [3])  # one keyframe: as a reference frame at 3, not made again
    check_keyframed(single, 9, 5, [3])


@pytest.mark.parametrize("args, match", [((5, 5, []), "at least one keyframe"), ((5, 5, [5]), "keyframe 5 outside"),
                                         ((5, 5, [0], "best"), "unknown sampling scheme")])
def test_bad_keyframes_are_refused(args, match) -> None:
    with pytest.raises(ValueError, match=match):
        plan_keyframed(*args)
