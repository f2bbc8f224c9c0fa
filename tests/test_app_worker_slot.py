"""WorkerSlot: one superqt worker of a kind at a time, emptied only by the worker in it (the render controller's model
build, formula preview and shot preparation)."""
import threading

import pytest

pytest.importorskip("PySide6")
pytest.importorskip("pytestqt")

from x2video_app._qt.worker_slot import WorkerSlot  # noqa: E402


def test_the_slot_empties_when_its_worker_finishes_and_reports(qtbot):
    done, errors = [], []
    slot = WorkerSlot(on_done=lambda: done.append(True))
    assert not slot.busy
    w = slot.start(lambda: 41 + 1, errored=errors.append)
    assert slot.busy and slot.worker is w
    qtbot.waitUntil(lambda: not slot.busy, timeout=10_000)
    assert done == [True] and errors == [] and slot.worker is None

    def fails():
        raise ValueError("no model")

    with qtbot.capture_exceptions() as raised:  # superqt also re-raises a worker's error in the event loop, as before
        slot.start(fails, errored=errors.append)
        qtbot.waitUntil(lambda: not slot.busy, timeout=10_000)
    assert len(errors) == 1 and isinstance(errors[0], ValueError) and done == [True, True]
    assert [type(e[1]) for e in raised] == [ValueError]


def test_a_replaced_worker_finishing_later_leaves_the_newer_one_in_the_slot(qtbot):
    release_old, release_new = threading.Event(), threading.Event()
    done = []
    slot = WorkerSlot(on_done=lambda: done.append(slot.worker))
    old = slot.start(lambda: release_old.wait(10))
    new = slot.start(lambda: release_new.wait(10))
    with qtbot.waitSignal(old.finished, timeout=10_000):
        release_old.set()
    assert slot.worker is new and done == []  # the old one's end did not empty the slot
    with qtbot.waitSignal(new.finished, timeout=10_000):
        release_new.set()
    assert slot.worker is None and done == [None]


def test_quit_stops_a_generator_at_its_next_yield(qtbot):
    yielded, stop = [], threading.Event()

    def frames():
        for i in range(1000):
            yield i
            stop.wait(0.01)

    slot = WorkerSlot()
    slot.start(frames, yielded=yielded.append)
    qtbot.waitUntil(lambda: len(yielded) >= 2, timeout=10_000)
    slot.quit()
    qtbot.waitUntil(lambda: not slot.busy, timeout=10_000)
    assert len(yielded) < 1000
    slot.quit()  # an empty slot: nothing to stop
