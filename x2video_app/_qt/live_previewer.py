"""The live preview's worker (issue 43): latest-wins rendering of single frames off the GUI thread, in a superqt
generator worker. At most one request waits, which the next one replaces (the stale one is dropped, never queued);
a preview in progress always finishes and shows while a newer one waits."""
from __future__ import annotations

import dataclasses
import logging
import threading
import time
from collections import deque
from typing import Any

from PySide6.QtCore import QObject, Signal
from superqt.utils import WorkerBase, create_worker

from x2video.render.events import CancelToken
from x2video_app.state.live_request import LiveRequest, LiveResult

log = logging.getLogger(__name__)


class _QuietHere(logging.Filter):
    """Drops the Renderer's per-render INFO lines logged by a live preview's thread (20 a second while dragging)."""

    def __init__(self) -> None:
        super().__init__()
        self.local = threading.local()

    def filter(self, record: logging.LogRecord) -> bool:
        return record.levelno > logging.INFO or not getattr(self.local, "on", False)


_QUIET = _QuietHere()
for _name in ("x2video.render.renderer", "x2video.tiers.residual", "x2video.tiers.diffusion"):
    logging.getLogger(_name).addFilter(_QUIET)


class LivePreviewer(QObject):
    """Latest-wins rendering of single frames in a superqt generator worker; sigResult(LiveResult) on the GUI thread.

    `submit` replaces the waiting request (counted in `dropped`) and cancels a full-quality sampler frame in progress
    (a per-frame preview in progress finishes: it is what keeps frames coming while a slider moves). `taken` records
    (request id, newest id) as each request starts, so tests can check nothing stale ran."""

    sigResult = Signal(object)

    def __init__(self, parent: QObject | None = None) -> None:
        super().__init__(parent)
        self._lock = threading.Lock()
        self._pending: LiveRequest | None = None
        self._active = False  # a worker is draining (set and cleared under the lock, so no request is stranded)
        self._newest = 0
        self._token: CancelToken | None = None  # the running full-quality request's
        self._workers: set[Any] = set()
        self._renderer: Any = None
        #: the conditioning cache the sampler's frames share with the window's Renderer (thread-safe), or None
        self.cache: Any = None
        self.submitted = 0
        self.dropped = 0
        self.taken: deque[tuple[int, int]] = deque(maxlen=10_000)

    @property
    def active(self) -> bool:
        """A request is waiting or rendering."""
        with self._lock:
            return self._active

    def submit(self, req: LiveRequest) -> None:
        with self._lock:
            self.submitted += 1
            if self._pending is not None:
                self.dropped += 1
            self._pending, self._newest = req, req.id
            if self._token is not None:
                self._token.cancel()
            start, self._active = not self._active, True
        if start:
            w = create_worker(self._drain)
            w.yielded.connect(self.sigResult.emit)
            w.finished.connect(lambda: self._workers.discard(w))
            self._workers.add(w)
            w.start()

    def cancel_final(self) -> None:
        """Stop a full-quality sampler frame in progress (a whole-shot render is starting) and drop what waits."""
        with self._lock:
            if self._pending is not None:
                self.dropped += 1
            self._pending = None
            if self._token is not None:
                self._token.cancel()

    def shutdown(self, wait_ms: int = 30_000) -> None:
        """Drop what waits, stop what runs, and wait for the worker's thread."""
        self.cancel_final()
        for w in list(self._workers):
            w.quit()
        if self._workers:
            WorkerBase.await_workers(wait_ms)

    # -- the worker thread -------------------------------------------------------
    def _take(self) -> tuple[LiveRequest | None, int, CancelToken | None]:
        with self._lock:
            req, self._pending = self._pending, None
            if req is None:
                self._active, self._token = False, None
                return None, self._newest, None
            self._token = CancelToken() if req.final else None
            self.taken.append((req.id, self._newest))
            return req, self._newest, self._token

    def _drain(self):
        while True:
            req, newest, token = self._take()
            if req is None:
                return
            yield self._run(req, newest, token)

    def _run(self, req: LiveRequest, newest: int, token: CancelToken | None) -> LiveResult:
        from x2video.render.live import preview_choice, render_frame  # torch: loaded by the model build already

        choice = req.choice if req.choice is not None else preview_choice(req.settings.quality, req.shot, req.edits, req.model, req.settings.base)
        full = req.final and choice.full is not None and not choice.same
        settings = req.settings if full else dataclasses.replace(req.settings, quality=choice.preview.tier)
        _QUIET.local.on = True
        try:
            frame = render_frame(self._renderer_for(req.model), req.shot, req.edits, settings, req.t, token)
            return LiveResult(req, frame, choice, newest, "" if frame is not None else "cancelled", time.perf_counter())
        except Exception as e:  # noqa: BLE001 - a preview never takes the editor down; the status bar says why
            log.warning("live preview of frame %d failed: %s", req.t, e)
            return LiveResult(req, None, choice, newest, f"{type(e).__name__}: {e}", time.perf_counter())
        finally:
            _QUIET.local.on = False

    def _renderer_for(self, model: Any) -> Any:
        from x2video.render.renderer import Renderer

        if self._renderer is None or self._renderer.model is not model:
            self._renderer = Renderer(model, cache=self.cache) if self.cache is not None else Renderer(model)
        return self._renderer
