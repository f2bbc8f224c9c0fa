"""`WorkerSlot`: one superqt worker of a kind at a time (the render controller's model build, formula preview and
shot preparation each have one), emptied when the worker in it finishes."""
from __future__ import annotations

from typing import Any, Callable

from superqt.utils import create_worker


class WorkerSlot:
    """Holds at most one worker. `start` runs `func` in a new worker and puts it in the slot (one running there is
    not stopped: `quit` it first); the slot empties when the worker in it finishes, then calls `on_done`. A replaced
    worker that finishes later leaves the newer one in place."""

    def __init__(self, on_done: Callable[[], None] | None = None) -> None:
        self.worker: Any = None  # superqt's FunctionWorker or GeneratorWorker; None when the slot is empty
        self._on_done = on_done

    @property
    def busy(self) -> bool:
        return self.worker is not None

    def start(self, func: Callable[[], Any], errored: Callable[[BaseException], None] | None = None,
              yielded: Callable[[Any], None] | None = None) -> Any:
        """Run `func` (a function, or a generator function whose values go to `yielded`) in a worker; the worker."""
        w = create_worker(func)
        if yielded is not None:
            w.yielded.connect(yielded)
        if errored is not None:
            w.errored.connect(errored)
        w.finished.connect(lambda: self._finished(w))
        self.worker = w
        w.start()
        return w

    def quit(self) -> None:
        """Ask the worker in the slot to stop (a generator stops at its next yield); it empties the slot as it ends."""
        if self.worker is not None:
            self.worker.quit()

    def _finished(self, w: Any) -> None:
        if self.worker is w:
            self.worker = None
            if self._on_done is not None:
                self._on_done()
