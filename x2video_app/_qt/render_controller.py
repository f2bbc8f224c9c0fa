"""Starts, feeds and cancels renders: keeps one long-lived Renderer (its latent cache survives between
renders), builds the model off the GUI thread, prepares the open shot's conditioning there before Render is
pressed (`Renderer.prepare`), shows the formula's preview of a render at once (the frame
on screen on the GUI thread, the rest in a worker beside the render), and applies the workers' events to
the Document.

Importing this module does not import torch (the Renderer's modules do): the window opens while the
model is still being built in the background."""
from __future__ import annotations

import copy
import logging
import threading
import time
from typing import Any, Callable

from PySide6.QtCore import QObject, Signal

from x2video.render.events import CancelToken, FramesReady, RenderEvent, RenderStarted
from x2video.render.settings import RenderSettings
from x2video.tiers.base import RenderPlan
from x2video_app._qt.render_worker import RenderWorker
from x2video_app._qt.worker_slot import WorkerSlot
from x2video_app.state.document import Document
from x2video_app.state.frame_sources import path_traced_frames
from x2video_app.state.model_source import ModelChoice, load_model
from x2video_app.state.preview import PreviewReady, preview_frame, preview_frames, preview_order

log = logging.getLogger(__name__)


def set_render_threads() -> int:
    """Torch threads for rendering: X2VIDEO_TORCH_THREADS, else all cores but one.

    The spare core keeps the GUI responsive, and on a busy machine oversubscribed OpenMP
    threads crawl: on the 2-core development machine, shared with other jobs, one thread
    rendered the demo shot about 10x faster than torch's default of two.
    """
    import os

    import torch

    env = os.environ.get("X2VIDEO_TORCH_THREADS")
    n = int(env) if env else max(1, (os.cpu_count() or 2) - 1)
    torch.set_num_threads(n)
    return n


def engine_threads() -> int:
    """Threads for the diffusion tier's exported graphs (`X2VideoModel.engine_threads`): X2VIDEO_TORCH_THREADS, else
    every core. Unlike torch's OpenMP threads these do not crawl when the machine is busy: on the 2-core
    development machine a UNet call on OpenVINO took 0.39 s on two threads and 0.69 s on one, and with the other
    core kept busy 0.66-0.70 s on two against 0.71-0.74 on one (ONNX Runtime: 0.50 / 0.87 s quiet, 0.99-1.13 /
    0.95-1.03 s busy); the editor's first diffusion keyframe came 1.03 s after Render instead of 1.2-1.5 s."""
    import os

    env = os.environ.get("X2VIDEO_TORCH_THREADS")
    return int(env) if env else (os.cpu_count() or 1)


def needs_model(quality: str) -> bool:
    """Whether a render at `quality` needs the model, without importing torch: tier 0's module is torch-free and
    registers itself; a quality not registered yet ('auto', or a tier whose module torch must load) is taken to."""
    from x2video.tiers import formula as tier_formula  # noqa: F401 - registers tier 0
    from x2video.tiers.base import TIERS

    cls = TIERS.get(quality)
    return cls is None or cls.needs_model


def is_out_of_memory(exc: BaseException) -> bool:
    text = f"{type(exc).__name__}: {exc}".lower()
    return isinstance(exc, MemoryError) or "out of memory" in text or "outofmemory" in text


def warm_up(renderer: Any) -> None:
    """What the first render would otherwise do before its first frame, done while the model is built: load
    the text encoder (about 1 s here; it loads on first use). Never fails the build."""
    model = getattr(renderer, "model", None)
    if getattr(model, "text_encoder", None) is None:
        return
    try:
        model.encode_prompts([""])
    except Exception as e:  # noqa: BLE001 - the render reports real errors
        log.warning("warming the text encoder failed: %s", e)


class RenderController(QObject):
    """sigEvent(event) after the Document applied it (a Renderer event or a `PreviewReady`); sigRunning(bool);
    sigError(kind, message); sigPreload(bool)."""

    sigEvent = Signal(object)
    sigRunning = Signal(bool)
    sigError = Signal(str, str)  # kind: "oom" | "weights" | "render"
    sigPreload = Signal(bool)  # the model is being built in the background

    def __init__(self, doc: Document, parent: QObject | None = None) -> None:
        super().__init__(parent)
        self.doc = doc
        self.choice: ModelChoice | None = None
        self.renderer: Any = None  # x2video.render.renderer.Renderer, built on first render
        self.worker: RenderWorker | None = None
        #: replaceable for tests: builds a Renderer from a ModelChoice (runs in the worker thread)
        self.renderer_factory: Callable[[ModelChoice], Any] = self._default_factory
        self.pressed_at: float | None = None
        self._preload_slot = WorkerSlot(on_done=self._preload_done)  # the model build
        self._preview_slot = WorkerSlot()  # the formula's preview of the render in progress
        self._prepare_slot = WorkerSlot()  # `Renderer.prepare` of the open shot, before Render is pressed
        self._prepare_token: CancelToken | None = None
        self._prepare_pending: RenderSettings | None = None  # asked for before the model was built: run after it
        #: preview every frame (False: only the frame on screen, so the rest does not share the CPU with the render)
        self.preview_all = True
        self._render_id = 0  # which render a preview belongs to (a late one from an earlier render is dropped)
        self._lock = threading.Lock()
        self._renderer_for: ModelChoice | None = None
        #: torch threads, set by the first model build (in its worker: importing torch on the GUI thread froze
        #: the window for seconds at start-up; the OpenMP setting is process-wide from any non-OpenMP thread)
        self.threads: int | None = None

    @property
    def preload_worker(self) -> Any:
        """The worker building the model in the background; None when none."""
        return self._preload_slot.worker

    @property
    def preview_worker(self) -> Any:
        """The worker making the formula's preview of the render in progress; None when none."""
        return self._preview_slot.worker

    @property
    def prepare_worker(self) -> Any:
        """The worker preparing the open shot's conditioning before Render is pressed; None when none."""
        return self._prepare_slot.worker

    @property
    def busy(self) -> bool:
        """A render, model build, preview or preparation runs."""
        return self.worker is not None or self._preload_slot.busy or self._preview_slot.busy or self._prepare_slot.busy

    def ensure_threads(self) -> None:
        if self.threads is None:
            self.threads = set_render_threads()

    @staticmethod
    def _default_factory(choice: ModelChoice) -> Any:
        from x2video.render.renderer import Renderer

        model = load_model(choice)
        model.engine_threads = engine_threads()
        return Renderer(model)

    def set_model(self, choice: ModelChoice | None) -> None:
        if choice != self.choice:
            self.choice = choice
            self.renderer = None  # a new model means a new Renderer (and cache)

    def _get_renderer(self) -> Any:
        """The Renderer for the current model choice, built on first use (worker threads only)."""
        with self._lock:
            self.ensure_threads()
            choice = self.choice
            if self.renderer is None or self._renderer_for != choice:
                renderer = self.renderer_factory(choice)
                warm_up(renderer)
                self.renderer = renderer
                self._renderer_for = choice
            return self.renderer

    def preload(self) -> None:
        """Build the model in the background now, so the first Render does not wait for it."""
        if self.choice is None or self._preload_slot.busy or (self.renderer is not None and self._renderer_for == self.choice):
            return
        self.sigPreload.emit(True)
        self._preload_slot.start(self._get_renderer, errored=lambda e: log.warning("model preload failed (the render will say why): %s", e))

    def prepare(self, settings: RenderSettings) -> None:
        """Encode the open shot's conditioning and build the engine's graphs in a worker (`Renderer.prepare`, after
        the model is built), so that the first network keyframe after Render costs only its denoising steps and
        decoding. A new call (another shot, other settings) replaces a running one; a render cancels it and
        reuses what it finished. Nothing happens without a shot or a model, and nothing is encoded for tiers 0/1."""
        if self.doc.shot is None or self.choice is None:
            return
        if self.renderer is None or self._renderer_for != self.choice:  # after the model build, never instead of it:
            self._prepare_pending = settings  # at start-up the window paints first, then the model builds, then this
            self.preload()
            return
        self._prepare_pending = None
        self._quit_prepare()
        shot, edits = self.doc.shot, copy.deepcopy(self.doc.edits)
        base_dir = self.doc.project_path.parent if self.doc.project_path is not None else None
        token = self._prepare_token = CancelToken()

        def work() -> int:
            renderer = self._get_renderer()
            if token.cancelled or self.worker is not None:  # a render started meanwhile: it encodes what it needs
                return 0
            return renderer.prepare(shot, settings, edits, token, base_dir=base_dir)

        self._prepare_slot.start(work, errored=lambda e: log.warning("preparing the shot failed (the render will say why): %s", e))

    def _quit_prepare(self) -> None:
        if self._prepare_token is not None:
            self._prepare_token.cancel()
        self._prepare_slot.quit()

    def _preload_done(self) -> None:
        self.sigPreload.emit(False)
        pending, self._prepare_pending = self._prepare_pending, None
        if pending is not None and self.renderer is not None and self.worker is None:
            self.prepare(pending)

    def residual_available(self) -> bool | None:
        """Whether the current model has the tier-1 network (quality 'residual'): the built model says;
        before it is built, the weights folder does (residual.safetensors); None when there is no model."""
        c = self.choice
        if c is None:
            return None
        if self.renderer is not None and self._renderer_for == c:
            return getattr(getattr(self.renderer, "model", None), "residual_net", None) is not None
        return c.kind == "pretrained" and c.path is not None and (c.path / "residual.safetensors").is_file()

    @property
    def running(self) -> bool:
        return self.worker is not None

    def settings(self, preset: str, seed: int, window: int, scheme: str, seams: bool = RenderSettings.seams,
                 noise_shared: float = RenderSettings.noise_shared, max_levels: int | None = None,
                 exposure: float | str = RenderSettings.exposure, quality: str = RenderSettings.quality,
                 base: str = RenderSettings.base) -> RenderSettings:
        return RenderSettings(preset=preset, seed=seed, window=window, scheme=scheme, seams=seams, noise="frame", noise_shared=noise_shared,
                              max_levels=max_levels, exposure=exposure, quality=quality, base=base)  # type: ignore[arg-type]

    def start(self, settings: RenderSettings) -> bool:
        """Start a render of the document's shot and edits; False when one is running or nothing is open.

        Unless the render is the formula itself, the formula's preview comes first: the frame on screen
        at once (here, when the model is built, so its modules are imported), the others in a worker
        beside the render; the render's frames replace them as they arrive."""
        if self.worker is not None or self.doc.shot is None or self.choice is None:
            return False
        self.pressed_at = time.perf_counter()
        self._quit_preview()
        self._render_id += 1
        model = getattr(self.renderer, "model", None)
        shot, edits = self.doc.shot, copy.deepcopy(self.doc.edits)  # the person keeps editing during the render
        planned = None
        if model is not None:  # else still loading: importing the tier modules here would wait for torch on the GUI thread
            from x2video.tiers import registry as tiers  # torch: imported by the built model already

            try:  # the progress bars follow the library's plan (windows per level, steps per window), not a guess of it
                planned = tiers.plan_render(shot, edits, settings, model)
            except Exception as e:  # a plan we cannot show must not stop the render; the Renderer reports the error
                log.warning("could not plan for the progress bars: %s", e)
        # without a plan, RenderStarted and StepDone fill in the windows and steps as the render starts
        self.doc.render.begin(planned.steps if planned else 0, planned.windows_per_level() if planned else {},
                              path_traced=path_traced_frames(shot, settings), irradiance_scale=shot.info.irradiance_scale)
        if needs_model(settings.quality):  # a render that needs no model is about as fast as the preview
            self._preview(shot, edits, model is not None)
        base_dir = self.doc.project_path.parent if self.doc.project_path is not None else None

        def run(shot, edits, settings, on_event, cancel):
            renderer = self._get_renderer()
            if cancel.cancelled:
                return None
            if planned is None:  # the model was still loading when Render was pressed: its plan, before the render's events
                try:
                    on_event(renderer.plan_render(shot, edits, settings))
                except Exception as e:  # the render reports real errors
                    log.warning("could not plan for the progress bars: %s", e)
            return renderer.render(shot, edits, settings, on_event, cancel, base_dir=base_dir)

        w = RenderWorker(run, shot, edits, settings)
        w.events.event.connect(self._on_event)
        w.errored.connect(self._on_error)
        w.finished.connect(self._on_finished)
        self.worker = w
        self.sigRunning.emit(True)
        w.start()
        return True

    def _preview(self, shot, edits, now: bool) -> None:
        """The formula's preview: the current frame here when `now` (the model is built, so the tier modules
        are imported and this takes milliseconds), then every other frame in a generator worker."""
        first, n = self.doc.frame, self.doc.num_frames
        done: list[int] = []
        if now:
            try:
                t0 = time.perf_counter()
                img = preview_frame(self.doc.conditioning(first))  # the live edits, which the copy equals now
                self._on_event(PreviewReady(frames={first: img}, seconds=time.perf_counter() - t0))
                done.append(first)
            except Exception as e:  # a preview must never stop the render; the render reports real errors
                log.warning("formula preview of frame %d failed: %s", first, e)
        if done and not self.preview_all:
            return
        preview_all = self.preview_all

        def frames():  # in the worker: the order needs the tier modules (torch), which may still be loading
            yield from preview_frames(shot, edits, preview_order(n, first, done) if preview_all else [first])

        rid = self._render_id
        self._preview_slot.start(frames, yielded=lambda ev: self._on_preview(rid, ev),
                                 errored=lambda e: log.warning("formula preview failed: %s", e))

    def _quit_preview(self) -> None:
        self._preview_slot.quit()

    def cancel(self) -> None:
        self._quit_preview()
        self._quit_prepare()
        if self.worker is not None:
            self.worker.quit()

    def wait(self, timeout_ms: int = 30000) -> bool:
        """Block (processing events) until the render, preview and preload workers end; for closing the window and tests."""
        from PySide6.QtCore import QCoreApplication, QDeadlineTimer

        deadline = QDeadlineTimer(timeout_ms)
        while self.busy and not deadline.hasExpired():
            QCoreApplication.processEvents()
            time.sleep(0.005)
        return not self.busy

    # -- slots (GUI thread) ----------------------------------------------------
    def _on_event(self, ev: RenderEvent | PreviewReady | RenderPlan) -> None:
        if isinstance(ev, RenderPlan):  # planned in the worker (the model was still loading): what the progress bars show
            self.doc.render.windows_per_level, self.doc.render.steps_per_window = ev.windows_per_level(), ev.steps
            return
        self.doc.render.apply(ev)
        if isinstance(ev, RenderStarted) and self.doc.render.per_frame:
            # a per-frame tier fills the shot about as fast as the preview and would share the CPU with it
            self._quit_preview()
        self.sigEvent.emit(ev)

    def _on_preview(self, render_id: int, ev: PreviewReady) -> None:
        if render_id == self._render_id:  # not a late one from an earlier render
            self._on_event(ev)

    def _on_error(self, exc: BaseException) -> None:
        if self.doc.render.status == "running":
            self.doc.render.fail(f"{type(exc).__name__}: {exc}")
        if isinstance(exc, FileNotFoundError):
            self.renderer = None
            self.sigError.emit("weights", str(exc))
        elif is_out_of_memory(exc):
            self.sigError.emit("oom", f"{type(exc).__name__}: {exc}")
        else:
            log.error("render failed", exc_info=exc)
            self.sigError.emit("render", f"{type(exc).__name__}: {exc}")

    def _on_finished(self) -> None:
        self._quit_preview()  # whatever it has not made yet, the render has
        w, self.worker = self.worker, None
        if w is not None and self.doc.render.status == "running":
            # cancelled before the Renderer started: nothing emitted RenderCancelled
            from x2video.render.events import RenderCancelled

            self._on_event(RenderCancelled(frames_done=sorted(self.doc.render.frames)))
        self.sigRunning.emit(False)


__all__ = ["RenderController", "is_out_of_memory", "FramesReady", "PreviewReady"]
