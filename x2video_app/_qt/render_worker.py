"""The render worker: runs `Renderer.render` off the GUI thread (a superqt worker) and forwards its typed events.

The core knows nothing of Qt: it calls `on_event(event)` from the worker thread; the worker
re-emits each event through `events.event`, a signal of a QObject made on the GUI thread, so Qt queues it there
(superqt's public API only: the worker's own signals stay superqt's). `quit()` sets
the `CancelToken`, which the sampler checks between denoising steps.
"""
from __future__ import annotations

import logging
from typing import Any, Callable

from PySide6.QtCore import QObject, Signal
from superqt.utils import WorkerBase

from x2video.render.events import CancelToken
from x2video.render.settings import RenderSettings

log = logging.getLogger(__name__)


class RenderEvents(QObject):
    event = Signal(object)  # one typed render event (x2video.render.events), on the GUI thread


class RenderWorker(WorkerBase):
    """`render(shot, edits, settings, on_event, cancel)` in a pool thread.

    `render` is the bound `Renderer.render` of the window's long-lived Renderer, so its
    conditioning-latent cache survives between renders.
    """

    def __init__(self, render: Callable[..., Any], shot, edits, settings: RenderSettings) -> None:
        super().__init__()
        self.events = RenderEvents()  # made here, on the GUI thread: emits from the pool thread are queued to it
        self._render = render
        self._args = (shot, edits, settings)
        self.token = CancelToken()

    def quit(self) -> None:
        """Ask the render to stop; it returns within one denoising step, keeping finished frames."""
        super().quit()
        self.token.cancel()

    def work(self) -> Any:
        shot, edits, settings = self._args
        return self._render(shot, edits, settings, on_event=self.events.event.emit, cancel=self.token)
