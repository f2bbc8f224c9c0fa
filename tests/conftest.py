"""Shared test set-up: offscreen Qt, offline model hubs, deterministic single-thread torch."""
import os

os.environ.setdefault("QT_QPA_PLATFORM", "offscreen")
os.environ.setdefault("HF_HUB_OFFLINE", "1")
os.environ.setdefault("TRANSFORMERS_OFFLINE", "1")
# tests that open the demo get the rasterized room in seconds, not a Cycles render (tests/test_demo.py path-traces one, small)
os.environ.setdefault("X2VIDEO_DEMO_RENDERER", "raster")


# --- Qt: fail any test that leaves a worker or thread running (editor tests; napari's pattern) ---------
import sys as _sys
import threading as _threading

import pytest as _pytest


@_pytest.fixture(autouse=True)
def _no_dangling_qt_threads(request):
    """After each editor test (tests/test_app_*.py): no superqt worker still registered, the Qt
    thread pool idle, no new non-daemon Python thread alive.

    A test that starts a render or export must wait for it (or cancel and wait) before it
    ends; otherwise this fails it. Other test files are left alone (their libraries may keep
    worker threads of their own).
    """
    if not request.node.path.name.startswith("test_app_"):
        yield
        return
    before = set(_threading.enumerate())
    yield
    if "PySide6" not in _sys.modules:
        return
    from PySide6.QtCore import QThreadPool

    problems = []
    if "superqt.utils" in _sys.modules:
        from superqt.utils import WorkerBase

        running = [w for w in WorkerBase._worker_set]
        if running:
            for w in running:  # do not let one test's worker poison the next: stop it, then fail
                w.quit()
            WorkerBase.await_workers(10_000)
            problems.append(f"{len(running)} superqt worker(s) still running: {running}")
    pool = QThreadPool.globalInstance()
    if not pool.waitForDone(2000):
        problems.append(f"{pool.activeThreadCount()} Qt thread-pool thread(s) still busy")
    extra = [t for t in _threading.enumerate() if t not in before and t.is_alive() and not t.daemon and t.name != "MainThread"]
    if extra:
        problems.append(f"non-daemon threads left running: {[t.name for t in extra]}")
    if problems:
        _pytest.fail("test left threads running: " + "; ".join(problems))


@_pytest.fixture
def torch_one_thread():
    """One torch thread for the test, restored after: many small passes on 2 shared cores run several times
    faster on one thread than on two fighting. Modules opt in with `pytestmark = pytest.mark.usefixtures(...)`."""
    import torch

    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)
