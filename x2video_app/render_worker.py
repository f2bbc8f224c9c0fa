"""The render worker: runs `Renderer.render` off the GUI thread (a superqt worker) and forwards its typed events.

The core knows nothing of Qt: it calls `on_event(event)` from the worker thread; the worker
re-emits each event through a Qt signal, which Qt queues onto the GUI thread. `quit()` sets
the `CancelToken`, which the sampler checks between denoising steps.
"""
from __future__ import annotations

import logging
from typing import Any, Callable

from PySide6.QtCore import Signal
from superqt.utils import WorkerBase
from superqt.utils._qthreading import WorkerBaseSignals

from x2video.sampling.events import CancelToken, RenderSettings

log = logging.getLogger(__name__)


class RenderWorkerSignals(WorkerBaseSignals):
    event = Signal(object)  # one typed render event (x2video.sampling.events), on the GUI thread


class RenderWorker(WorkerBase):
    """`render(shot, edits, settings, on_event, cancel)` in a pool thread.

    `render` is the bound `Renderer.render` of the window's long-lived Renderer, so its
    conditioning-latent cache survives between renders.
    """

    def __init__(self, render: Callable[..., Any], shot, edits, settings: RenderSettings) -> None:
        super().__init__(SignalsClass=RenderWorkerSignals)
        self._render = render
        self._args = (shot, edits, settings)
        self.token = CancelToken()

    def quit(self) -> None:
        """Ask the render to stop; it returns within one denoising step, keeping finished frames."""
        super().quit()
        self.token.cancel()

    def work(self) -> Any:
        shot, edits, settings = self._args
        return self._render(shot, edits, settings, on_event=self.signals.event.emit, cancel=self.token)
