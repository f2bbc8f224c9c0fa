"""Recursive Sampling and sequential frame plans: exhaustive invariants for L in 1..300, N in 2..9."""
from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from x2video.sampling.planner import Window, last_use, num_levels, plan_recursive, plan_sequential, shift


def check_plan(plan: list[Window], length: int, window: int, ref_frame: int | None = None) -> None:
    produced: set[int] = set()
    counts = [0] * length
    for i, w in enumerate(plan):
        assert 1 <= len(w.frames) <= window, (i, w)
        assert set(w.generate) <= set(w.frames) and set(w.refs) <= set(w.frames), w
        assert not set(w.generate) & set(w.refs), w
        assert set(w.refs) <= produced, f"window {i} reads {set(w.refs) - produced} before they exist"
        assert not set(w.generate) & produced, f"window {i} regenerates {set(w.generate) & produced}"
        assert set(w.frames) == set(w.generate) | set(w.refs), w
        for f in w.generate:
            counts[f] += 1
        produced |= set(w.generate)
        if w.mode == "interp":
            assert w.refs == (w.frames[0], w.frames[-1]) and w.ref_positions == (0, len(w.frames) - 1)
            stride = (window - 1) ** (w.level - 1)
            steps = [b - a for a, b in zip(w.frames, w.frames[1:])]
            assert all(s == stride for s in steps[:-1]) and 0 < steps[-1] <= stride, w
        else:
            assert w.refs in ((), (w.frames[0],)), w
            assert w.ref_positions in ((), (0,)), w
    assert counts == [1] * length, "every frame is produced exactly once"
    levels = [w.level for w in plan]
    assert levels == sorted(levels, reverse=True), "keyframes before level 2 before level 1"
    users = [i for i, w in enumerate(plan) if w.user_ref]
    if ref_frame is None:
        assert users == []
    else:
        assert users == [0] and plan[0].frames[0] == ref_frame


def test_recursive_exhaustive() -> None:
    for window in range(2, 10):
        for length in range(1, 301):
            plan = plan_recursive(length, window)
            check_plan(plan, length, window)
            keys = [w for w in plan if w.mode == "key"]
            if window > 2:
                assert len(keys) == 1 and keys[0].level == num_levels(length - 1, window), (length, window)
                # first interpolation happens only after all keyframes
                assert plan[0].mode == "key"


def test_sequential_exhaustive() -> None:
    for window in range(2, 10):
        for length in range(1, 301):
            plan = plan_sequential(length, window)
            check_plan(plan, length, window)
            for prev, w in zip(plan, plan[1:]):
                assert w.refs == (prev.frames[-1],) and w.frames[0] == prev.frames[-1]
                assert list(w.frames) == list(range(w.frames[0], w.frames[0] + len(w.frames)))


@settings(max_examples=300, deadline=None)
@given(st.integers(1, 300), st.integers(2, 9), st.data())
def test_with_reference_frame(length: int, window: int, data: st.DataObject) -> None:
    ref = data.draw(st.integers(0, length - 1))
    check_plan(plan_recursive(length, window, ref), length, window, ref)
    check_plan(plan_sequential(length, window, ref), length, window, ref)


def test_paper_example_65_frames() -> None:
    """Paper Fig. recursive_sample: N=5, K=3, L=65."""
    plan = plan_recursive(65, 5)
    assert plan[0] == Window((0, 16, 32, 48, 64), (0, 16, 32, 48, 64), (), "key", 3)
    assert plan[1] == Window((0, 4, 8, 12, 16), (4, 8, 12), (0, 16), "interp", 2)
    assert [w.level for w in plan].count(2) == 4 and [w.level for w in plan].count(1) == 16
    with_ref = plan_recursive(65, 5, ref_frame=0)
    assert with_ref[0].user_ref and with_ref[0].ref_positions == (0,)


def test_uneven_tail_keeps_strides() -> None:
    plan = plan_recursive(18, 5)
    assert plan[0].frames == (0, 16, 17)
    assert all(w.frames != (16, 17) for w in plan[1:]), "adjacent keyframes need no window"


def test_last_use_and_shift() -> None:
    plan = plan_recursive(17, 5)
    lu = last_use(plan)
    assert lu[16] == 4 and lu[0] == 1 and 1 not in lu
    moved = shift(plan, 100)
    assert moved[0].frames == (100, 104, 108, 112, 116) and moved[1].refs == (100, 104)


@pytest.mark.parametrize("args", [(0, 5), (10, 1), (10, 5, 10), (10, 5, -1)])
def test_bad_arguments(args: tuple[int, ...]) -> None:
    with pytest.raises(ValueError, match="frame|window"):
        plan_recursive(*args)


def check_seams(length: int, window: int, ref: int | None) -> None:
    """The seam plan is the plain plan with windows inserted that only re-make frames already made."""
    base, plan = plan_recursive(length, window, ref), plan_recursive(length, window, ref, seams=True)
    extra = [w for w in plan if w not in base]
    assert [w for w in plan if w in base] == base
    produced: set[int] = set()
    for w in plan:
        assert set(w.refs) <= produced, (length, window, ref, w)
        if w in extra:
            levels = num_levels(length - 1 if ref is None else max(ref, length - 1 - ref), window)
            assert set(w.generate) <= produced and levels >= 3 and w.level == levels - 1
            assert not set(w.generate) & set(w.refs) and 2 <= len(w.frames) <= window
            steps = {abs(b - a) for a, b in zip(w.frames, w.frames[1:])}
            assert steps == {(window - 1) ** (w.level - 1)}, w  # the level's exact stride, no uneven tails
            if w.user_ref:
                assert w.frames[0] == ref and w.mode == "interp" and w.ref_positions == (0, len(w.frames) - 1)
        produced |= set(w.generate)
    assert produced == set(range(length))
    made = [f for w in extra for f in w.generate]
    assert len(made) == len(set(made)), "a seam window makes each frame at most once more"


def test_seam_pass_exhaustive() -> None:
    for window in range(2, 10):
        for length in range(1, 150):
            for ref in {None, 0, length // 2, length - 1}:
                check_seams(length, window, ref)


def test_seam_pass_65_frames() -> None:
    plan = plan_recursive(65, 5, seams=True)
    base = plan_recursive(65, 5)
    extra = [w for w in plan if w not in base]
    assert [plan.index(w) for w in extra] == list(range(5, 10)), "right after level 2, before level 1"
    assert extra == [
        Window((8, 4, 0), (4, 0), (8,), "key", 2),
        Window((8, 12, 16, 20, 24), (12, 16, 20), (8, 24), "interp", 2),
        Window((24, 28, 32, 36, 40), (28, 32, 36), (24, 40), "interp", 2),
        Window((40, 44, 48, 52, 56), (44, 48, 52), (40, 56), "interp", 2),
        Window((56, 60, 64), (60, 64), (56,), "key", 2),
    ]
    # with the user's reference at frame 0, frame 0 keeps it: an interpolation window from the reference
    first = [w for w in plan_recursive(65, 5, 0, seams=True) if w not in plan_recursive(65, 5, 0)][0]
    assert first == Window((0, 4, 8), (0, 4), (8,), "interp", 2, user_ref=True)
    # two levels: no pass (it would double level 1 to re-make keyframes 4 frames apart); three from 18 frames
    assert plan_recursive(17, 5, seams=True) == plan_recursive(17, 5)
    assert plan_recursive(18, 5, seams=True) != plan_recursive(18, 5)


def test_max_levels_exhaustive() -> None:
    """Capping K keeps every plan invariant; the keyframes are (N-1)^(K-1) apart in chained windows."""
    for window in range(3, 8):
        for length in range(1, 140):
            full = num_levels(length - 1, window)
            for cap in range(1, full + 2):
                plan = plan_recursive(length, window, max_levels=cap)
                check_plan(plan, length, window)
                k = min(cap, full)
                assert max(w.level for w in plan) == k if length > 1 else True
                keys = [w for w in plan if w.mode == "key"]
                stride = (window - 1) ** (k - 1)
                assert sorted({f for w in keys for f in w.generate}) == sorted(set(range(0, length, stride)) | {length - 1})
                if cap >= full:
                    assert plan == plan_recursive(length, window), "a cap at or above K changes nothing"


def test_max_levels_65_frames() -> None:
    """K = 2 at 65 frames: four chained keyframe windows at stride 4, then sixteen level-1 windows."""
    plan = plan_recursive(65, 5, ref_frame=0, max_levels=2)
    keys = [w for w in plan if w.mode == "key"]
    assert [w.frames for w in keys] == [tuple(range(s, s + 17, 4)) for s in (0, 16, 32, 48)]
    assert keys[0].user_ref and [w.refs for w in keys[1:]] == [(16,), (32,), (48,)]
    assert [w.level for w in plan].count(1) == 16 and all(w.mode == "interp" for w in plan[4:])
    assert plan_recursive(65, 5, max_levels=1) == [
        Window(w.frames, w.generate, w.refs, "key", 1, w.user_ref) for w in plan_sequential(65, 5)]
    with pytest.raises(ValueError, match="max_levels"):
        plan_recursive(65, 5, max_levels=0)
