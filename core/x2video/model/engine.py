"""CPU inference engine for the diffusion tier (issue 31): the video UNet, the VAE decoder and the channel encoder
exported to ONNX and run by OpenVINO or ONNX Runtime; PyTorch stays the reference (`tests/test_engine.py`
checks each part against it).

    RenderSettings.engine   what runs the three parts
      torch                 PyTorch (the reference; the only engine on a GPU or in half precision)
      onnx                  ONNX Runtime's CPU provider
      openvino              OpenVINO's CPU plugin, reading the same ONNX graphs
      auto                  OpenVINO when installed, else ONNX Runtime, else PyTorch; untrained weights: PyTorch
                            (fastest first as measured on the 2-core development machine, `python -m bench.render
                            --engines torch,onnx,openvino --parts 3`: bench/results/render/)

bfloat16 (the CPU here has AVX512-BF16, no AMX): OpenVINO's bf16 precision hint ran the UNet about 1.9x faster
than its f32 but moved v by up to 0.09 (f32: 3e-6), so it is not used; the decoder stays fp32 (bf16 decoding cost
temporal consistency before, docs/evaluations/).

Export (`torch.onnx.export`, the TorchScript tracer, opset 17): the UNet's Hybrid Self-Attention and Masked
Cross-Attention choose branches in Python from the per-call `AttnContext` (mode, LoRA branch of the level,
reference positions, whether alpha is non-zero), so one graph holds one such choice at one window size N and
latent size (h, w): a *variant*. `unet_variant` names it, collapsing what does not change the graph (the level
outside interpolation windows, the level beyond the model's LoRA branches, reference positions that select
the same frames). The decoder and the channel encoder have a dynamic batch and a static frame size. Where
a call cannot use a graph the part runs in PyTorch for that call, and the log says so once:
  * local prompts (Masked Cross-Attention's local branch: their count P and masks vary per edit; PyTorch);
  * per-frame timesteps (the samplers pass one scalar per call; training passes vectors and never comes here);
  * an encoder in bfloat16 (`--bf16-encoder` gives other latents than an fp32 graph would).

Exported graphs are cached on disk under $XDG_CACHE_HOME/x2video/engine (default ~/.cache), keyed by a
digest of the weights, the variant and the shapes, so each variant is exported once per machine (seconds
on 2 cores); OpenVINO keeps its compiled blobs beside them. Compiled graphs stay in memory per model, at most
`UNET_GRAPHS` UNet graphs (the least recently used is released: a long shot's finished levels). OpenVINO runs
without CPU pinning (two processes pinned their threads to the same core).
"""
from __future__ import annotations

import hashlib
import io
import logging
import os
import threading
from collections import OrderedDict
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np
import torch
from torch import nn

log = logging.getLogger(__name__)

#: the values of `RenderSettings.engine`
ENGINES = ("auto", "torch", "onnx", "openvino")
#: ONNX opset of the exported graphs (scaled_dot_product_attention and GroupNorm export at 17)
OPSET = 17
#: bumped when what is exported changes, so old cached graphs are not reused
FORMAT = 1


class EngineError(RuntimeError):
    """A part could not be exported or compiled for the chosen engine (the message says which and why)."""


def ort_session(model: str | bytes, threads: int, arena: bool = False) -> Any:
    """An ONNX Runtime CPU session for our graphs (the diffusion tier's here, the tier-1 net's in
    `x2video.model.residual_engine`): `threads` intra-op threads, no inter-op pool, quiet, and no memory pattern.
    No memory arena unless `arena`: with one kept across calls a fast-preset render of 33 frames at 320x224 peaked
    at 3.6 GB (each graph's arena kept its largest batch; 1.7 GB without, 16 % more time) and a 1920x1080 tier-1
    frame left the process 0.8 GB larger for good (0.3 GB without, about 9 % more time at that size) on the
    2-core VM. With `arena`, run it with `arena_released` so the arena is handed back at the end of each call."""
    import onnxruntime as ort

    so = ort.SessionOptions()
    so.intra_op_num_threads = threads
    so.inter_op_num_threads = 1
    so.log_severity_level = 3
    so.enable_cpu_mem_arena = arena
    so.enable_mem_pattern = False
    return ort.InferenceSession(model, so, providers=["CPUExecutionProvider"])


def arena_released() -> Any:
    """ONNX Runtime run options that shrink a session's memory arena at the end of the call: within the call its
    tensors reuse the memory of those freed before them (without an arena each large one is fresh pages: 3,400
    page faults, about 5 ms of a 320x224 tier-1 frame's 70), and what is free at its end is handed back (the region
    that holds the call's outputs at the end of the next call). On the 2-core VM two 1920x1080 tier-1 frames in
    tiles peaked at 783 MB and left the process 246 MB larger (without an arena 925 MB and 401 MB, most of it
    glibc's heap until trimmed)."""
    import onnxruntime as ort

    ro = ort.RunOptions()
    ro.add_run_config_entry("memory.enable_memory_arena_shrinkage", "cpu:0")
    return ro


def cache_dir() -> Path:
    """Where exported graphs and compiled blobs live: $XDG_CACHE_HOME/x2video/engine (default ~/.cache)."""
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "x2video" / "engine"


def available(runtime: str) -> bool:
    """Whether `runtime` ('onnx' or 'openvino') can be imported here."""
    import importlib.util

    name = {"onnx": "onnxruntime", "openvino": "openvino"}[runtime]
    return importlib.util.find_spec(name) is not None


def resolve(engine: str, device: torch.device | str = "cpu", dtype: torch.dtype = torch.float32, untrained: bool = False) -> str:
    """The runtime `engine` means for a model on `device` in `dtype`: 'torch', 'onnx' or 'openvino'.
    'auto' takes the fastest one installed (OpenVINO, then ONNX Runtime) for trained float32 weights on a CPU,
    else PyTorch: UNTRAINED weights (tests, smoke renders) render a few frames once, for which exporting the
    graphs costs more than it saves. Asking for a runtime that is missing or cannot apply is an error naming
    the setting."""
    if engine not in ENGINES:
        raise ValueError(f"RenderSettings.engine must be one of {', '.join(ENGINES)}, got {engine!r}")
    cpu32 = torch.device(device).type == "cpu" and dtype == torch.float32
    if engine == "auto":
        if not cpu32 or untrained:
            return "torch"
        return next((r for r in ("openvino", "onnx") if available(r)), "torch")
    if engine != "torch":
        if not cpu32:
            raise ValueError(f"engine {engine!r} runs float32 models on the CPU; this model is {dtype} on {device} (use engine 'torch')")
        if not available(engine):
            pkg = {"onnx": "onnxruntime", "openvino": "openvino"}[engine]
            raise ValueError(f"engine {engine!r} needs the {pkg} package, which is not installed (pip install {pkg}, or engine 'auto')")
    return engine


def module_digest(module: nn.Module) -> str:
    """sha256 of a module's tensors (names, dtypes, shapes, values): what an exported graph bakes in."""
    h = hashlib.sha256()
    for k, v in sorted(module.state_dict().items()):
        t = v.detach().to("cpu").contiguous()
        h.update(f"{k}{t.dtype}{tuple(t.shape)}".encode())
        h.update(t.reshape(-1).view(torch.uint8).numpy().tobytes() if t.numel() else b"")
    return h.hexdigest()


def unet_variant(mode: str, level: int, ref_positions: Sequence[int], num_frames: int, interp_levels: int) -> tuple:
    """What of one UNet call's `AttnContext` shapes the traced graph, with equivalent calls made equal."""
    from x2video.model.context import AttnContext

    ctx = AttnContext(num_frames=num_frames, latent_size=(1, 1), ref_positions=tuple(ref_positions), mode=mode, level=level)
    return (mode if mode == "interp" else "key", ctx.temporal_branch(interp_levels), ctx.source_positions(), num_frames)


class _Graph:
    """One compiled graph: feeds by input name -> first output."""

    def __init__(self, runtime: str, path: Path, threads: int) -> None:
        self.runtime = runtime
        if runtime == "onnx":
            self._sess = ort_session(str(path), threads)
            self.inputs = [i.name for i in self._sess.get_inputs()]
        else:
            import openvino as ov

            core = ov.Core()
            core.set_property({"CACHE_DIR": str(path.parent / "openvino")})
            # compiled from the file's path, OpenVINO finds its cached blob without parsing the ONNX: 0.43-0.55 s and
            # 40 MB less than read_model + compile_model (0.65-0.8 s) for a UNet graph on the 2-core VM.
            # No CPU pinning: OpenVINO pins its threads by default, and two processes (two farm workers, the editor
            # beside a CLI render) then share the same core while the other idles: a keyframe UNet call took 1.0 s in
            # each of two processes instead of 0.44 s (0.44-0.46 s unpinned; one process alone: the same either way).
            compiled = core.compile_model(str(path), "CPU", {"INFERENCE_NUM_THREADS": threads, "INFERENCE_PRECISION_HINT": "f32",
                                                             "ENABLE_CPU_PINNING": False})
            self._req = compiled.create_infer_request()
            self._lock = threading.Lock()  # one infer request: one call at a time
            self.inputs = [sorted(p.get_names())[0] for p in compiled.inputs]
            self._ports = {n: i for i, p in enumerate(compiled.inputs) for n in p.get_names()}

    def __call__(self, feeds: dict[str, np.ndarray]) -> np.ndarray:
        if self.runtime == "onnx":
            return self._sess.run(None, {k: feeds[k] for k in self.inputs})[0]
        args = {self._ports[k]: np.require(v, requirements="C") for k, v in feeds.items() if k in self._ports}
        with self._lock:
            return np.array(self._req.infer(args)[0], copy=True)


class _UNetCall(nn.Module):
    """One UNet call with the `AttnContext` choices fixed (the variant); what is exported."""

    def __init__(self, unet: nn.Module, prediction: str, num_frames: int, ref_positions: tuple, mode: str, level: int) -> None:
        super().__init__()
        self.unet, self.prediction = unet, prediction
        self.kw = dict(num_frames=num_frames, ref_positions=ref_positions, mode=mode, level=level)

    def forward(self, x: torch.Tensor, t: torch.Tensor, cond: torch.Tensor, ref: torch.Tensor, text: torch.Tensor) -> torch.Tensor:
        from x2video.model.inputs import run_unet

        return run_unet(self.unet, x, t, cond, ref, text_global=text, prediction=self.prediction, **self.kw)


class _Decode(nn.Module):
    def __init__(self, vae: nn.Module) -> None:
        super().__init__()
        self.vae = vae

    def forward(self, z: torch.Tensor) -> torch.Tensor:
        return self.vae.decode(z).sample  # (N, 3, H, W) in the VAE's range


class _EncodeMode(nn.Module):
    """The VAE encoder's posterior mode (what `encode_mode` returns), for models without a distilled channel encoder."""

    def __init__(self, vae: nn.Module) -> None:
        super().__init__()
        self.vae = vae

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.vae.encode(x).latent_dist.mode()


#: UNet graphs a `CompiledParts` keeps compiled at once; beyond, the least recently used is released. Each holds its
#: weights and its static activation buffers (the attention over a window's tokens): about 200 MB for a 5-frame
#: window at 320x224 on OpenVINO, so a 1,000-frame shot's 8 variants held 1.6 GB. A recursive render uses at most
#: 2 variants at a time, level after level, and shots up to 129 frames at N = 5 use at most 4 (the editor's
#: re-renders recompile nothing); a released graph comes back from OpenVINO's blob cache in about 0.5 s.
UNET_GRAPHS = 4


class CompiledParts:
    """One model's UNets, VAE decoder and channel encoder as graphs for one runtime ('onnx' or 'openvino'),
    exported on first use per variant and shape, cached on disk (`cache_dir`) and in memory (at most
    `max_unet_graphs` UNet graphs, least recently used released first). Each method returns None where a
    call cannot use a graph (see the module docstring); the model then runs PyTorch."""

    def __init__(self, model: Any, runtime: str, threads: int | None = None, folder: Path | None = None,
                 max_unet_graphs: int = UNET_GRAPHS) -> None:
        if runtime not in ("onnx", "openvino"):
            raise ValueError(f"CompiledParts runs 'onnx' or 'openvino', not {runtime!r}")
        if max_unet_graphs < 1:
            raise ValueError(f"max_unet_graphs must be at least 1, got {max_unet_graphs}")
        self.model, self.runtime = model, runtime
        self.threads = int(threads or torch.get_num_threads())
        self.folder = folder or cache_dir()
        self.max_unet_graphs = int(max_unet_graphs)
        self._graphs: OrderedDict[tuple, _Graph] = OrderedDict()  # least recently used first
        #: UNet graphs released to stay within `max_unet_graphs` (a variant compiled again counts again)
        self.released = 0
        self._digests: dict[int, str] = {}
        self._lock = threading.Lock()  # held while a graph is built
        self._held = threading.Lock()  # guards `_graphs` (brief)
        self._said: set[str] = set()
        #: wall seconds spent exporting and compiling graphs (a cold cache's one-time cost)
        self.build_seconds = 0.0

    # -- the parts --------------------------------------------------------------------
    def unet(self, x_t: torch.Tensor, t: torch.Tensor, window: Any, *, lcm: bool) -> torch.Tensor | None:
        """v-prediction (N, 4, h, w) of one window (`WindowInputs`), or None where the graph cannot apply."""
        if window.text_local.shape[0] > 0:
            self._once("local", "local prompts: the UNet runs in PyTorch for this render (their count and masks are not in the graph)")
            return None
        t = torch.as_tensor(t)
        if t.ndim != 0:
            return None
        model = self.model
        unet = model.lcm_unet if lcm else model.unet
        n, _, h, w = x_t.shape
        variant = unet_variant(window.mode, window.level, window.ref_positions, n, model.config.hybrid.interp_levels)
        mode, branch, sources, _ = variant
        level = int(branch[6:]) if branch.startswith("interp") else 1
        ref_positions = tuple(sources) if mode == "interp" else ()
        feeds = {"x": x_t, "t": t.to(torch.int64), "cond": window.cond, "ref": window.ref, "text": window.text_global}

        def make() -> tuple[nn.Module, tuple, dict]:
            from x2video.model.inputs import sd_alphas_cumprod

            sd_alphas_cumprod()  # computed (and cached) eagerly: the tracer cannot export its cumprod
            wrapper = _UNetCall(unet, model.config.prediction, n, ref_positions, mode, level)
            return wrapper, tuple(feeds[k] for k in ("x", "t", "cond", "ref", "text")), {}

        shapes = tuple((k, tuple(v.shape)) for k, v in feeds.items())
        key = ("lcm_unet" if lcm else "unet", id(unet), variant, shapes)
        graph = self._graph(key, unet, make, list(feeds))
        arrays = {k: v.detach().cpu().numpy() if k == "t" else v.detach().float().cpu().numpy() for k, v in feeds.items()}
        return torch.from_numpy(graph(arrays))

    def decode(self, z: torch.Tensor) -> torch.Tensor:
        """The VAE decoder's raw output (N, 3, H, W) for latents z (N, 4, h, w) already divided by the scale."""
        vae = self.model.vae

        def make() -> tuple[nn.Module, tuple, dict]:
            return _Decode(vae), (z,), {"z": {0: "n"}, "out": {0: "n"}}

        graph = self._graph(("decode", id(vae), tuple(z.shape[1:])), vae, make, ["z"])
        return torch.from_numpy(graph({"z": z.detach().float().cpu().numpy()}))

    def encode(self, x: torch.Tensor) -> torch.Tensor | None:
        """(N, 4, h, w) unscaled latents of images x (N, 3, H, W) in [-1, 1] by the channel encoder (the
        distilled one when the model has it, else the VAE encoder's mode); None for a bfloat16 encoder."""
        model = self.model
        if model.encoder_dtype != torch.float32:
            self._once("bf16", "a bfloat16 encoder runs in PyTorch (an fp32 graph would give other latents)")
            return None
        module = model.channel_encoder if model.channel_encoder is not None else _EncodeMode(model.vae)
        owner = model.channel_encoder if model.channel_encoder is not None else model.vae

        def make() -> tuple[nn.Module, tuple, dict]:
            return module, (x.float(),), {"x": {0: "n"}, "out": {0: "n"}}

        graph = self._graph(("encode", id(owner), tuple(x.shape[1:])), owner, make, ["x"])
        return torch.from_numpy(graph({"x": x.detach().float().cpu().numpy()}))

    # -- graphs -------------------------------------------------------------------------
    def unet_graphs(self) -> list[tuple]:
        """The variants of the UNet graphs held now, least recently used first."""
        with self._held:
            return [k[2] for k in self._graphs if k[0] in ("unet", "lcm_unet")]

    def _lookup(self, key: tuple) -> _Graph | None:
        with self._held:
            graph = self._graphs.get(key)
            if graph is not None:
                self._graphs.move_to_end(key)
            return graph

    def _graph(self, key: tuple, owner: nn.Module, make: Callable[[], tuple[nn.Module, tuple, dict]], names: list[str]) -> _Graph:
        graph = self._lookup(key)
        if graph is not None:
            return graph
        with self._lock:  # one build at a time; calls on graphs already built go on meanwhile
            graph = self._lookup(key)
            if graph is None:
                import time

                t0 = time.perf_counter()
                path = self._exported(key, owner, make, names)
                try:
                    graph = _Graph(self.runtime, path, self.threads)
                except Exception as e:  # noqa: BLE001 - re-raised with the part and the file named
                    raise EngineError(f"{self.runtime} could not compile {path} ({key[0]}): {type(e).__name__}: {e}") from e
                self.build_seconds += time.perf_counter() - t0
                with self._held:
                    self._graphs[key] = graph
                    unets = [k for k in self._graphs if k[0] in ("unet", "lcm_unet")]
                    released = unets[:max(0, len(unets) - self.max_unet_graphs)]
                    for old in released:
                        del self._graphs[old]  # a call still running on it keeps it alive until it returns
                    self.released += len(released)
                for old in released:
                    log.info("engine: released the %s graph %s (%d UNet graphs at most)", old[0], old[2], self.max_unet_graphs)
        return graph

    def _digest(self, module: nn.Module) -> str:
        d = self._digests.get(id(module))
        if d is None:
            d = self._digests[id(module)] = module_digest(module)
        return d

    def _exported(self, key: tuple, owner: nn.Module, make: Callable[[], tuple[nn.Module, tuple, dict]], names: list[str]) -> Path:
        """The ONNX file of `key`, exported now unless the cache has it."""
        tag = repr((FORMAT, OPSET, torch.__version__, key[0], key[2:], self._digest(owner)))
        path = self.folder / f"{key[0]}-{hashlib.sha256(tag.encode()).hexdigest()[:24]}.onnx"
        if path.is_file():
            return path
        from x2video.io.atomic import write_bytes_atomic

        module, args, axes = make()
        buf = io.BytesIO()
        log.info("engine: exporting %s %s to %s (once per weights, variant and size)", key[0], key[2:], path)
        try:
            with torch.no_grad():
                torch.onnx.export(module.eval(), args, buf, input_names=names, output_names=["out"], dynamic_axes=axes or None,
                                  opset_version=OPSET, dynamo=False)
        except Exception as e:  # noqa: BLE001 - re-raised with the part named
            raise EngineError(f"could not export {key[0]} {key[2:]} to ONNX: {type(e).__name__}: {e}") from e
        path.parent.mkdir(parents=True, exist_ok=True)
        write_bytes_atomic(path, buf.getvalue())
        return path

    def _once(self, what: str, message: str) -> None:
        if what not in self._said:
            self._said.add(what)
            log.info("engine %s: %s", self.runtime, message)
