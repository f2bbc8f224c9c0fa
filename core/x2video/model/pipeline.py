"""`X2VideoModel`: the `RenderModel` the samplers drive (paper Fig. overview): VAE + text encoder + video UNet + schedule.

Holds a video UNet (Hybrid Self-Attention, Masked Cross-Attention) or an image UNet (the
per-frame XRGB-style baseline: frames run independently), a frozen `AutoencoderKL`, a text
encoder and the `ModelConfig` with its latent scaling factors. `X2VideoModel.untrained(...)`
builds randomly initialised weights for tests and demos; its output is noise-like and its
`content_key()` starts with "untrained".
"""
from __future__ import annotations

import copy
import hashlib
import logging
import os
from pathlib import Path
from typing import Sequence

import numpy as np
import torch
from diffusers import AutoencoderKL, UNet2DConditionModel

from x2video.conditioning.frame import FrameConditioning
from x2video.model.api import WindowInputs
from x2video.model.channel_encoder import ChannelEncoder
from x2video.model.checkpoint import PARTS, load_into, read_config, save_checkpoint
from x2video.model.cond_latents import ConditioningLatents
from x2video.model.config import CHANNEL_ENCODERS, DEFAULT_CHANNEL_ENCODER, ModelConfig, preset
from x2video.model.inputs import cond_channels, is_video_unet, prior_latents, run_unet, sd_alphas_cumprod
from x2video.model.shading import shading_available
from x2video.model.text import TextEncoder, build_text_encoder
from x2video.model.unet import build_unet, convert_image_to_video
from x2video.model.vae import build_vae, encode_mode, from_vae_range_rgb, images_to_tensor, to_vae_range

log = logging.getLogger(__name__)

def _prepare(module: torch.nn.Module, device: torch.device, dtype: torch.dtype) -> torch.nn.Module:
    """Frozen, eval mode, on device; cast only when the dtype differs (diffusers warns on every cast)."""
    module = module.to(device)
    if next(module.parameters()).dtype != dtype:
        module = module.to(dtype)
    return module.eval().requires_grad_(False)


class X2VideoModel(ConditioningLatents):
    """Implements `x2video.model.api.RenderModel` (see there for the contract of each method)."""

    def __init__(
        self,
        config: ModelConfig,
        unet: UNet2DConditionModel,
        vae: AutoencoderKL,
        text_encoder: TextEncoder | None = None,
        lcm_unet: UNet2DConditionModel | None = None,
        *,
        device: torch.device | str = "cpu",
        dtype: torch.dtype = torch.float32,
        untrained: bool = False,
        encode_batch: int = 8,
        encoder_dtype: torch.dtype | None = None,
        channel_encoder: ChannelEncoder | None = None,
    ) -> None:
        self.config = config
        self.device = torch.device(device)
        self.dtype = dtype
        self.unet = _prepare(unet, self.device, dtype)
        self.vae = _prepare(vae, self.device, dtype)
        #: dtype the VAE's encoder runs in (the channel encoding); its latents are handed over in `dtype`
        #: and the decoder keeps `dtype`. See `from_pretrained`.
        self.encoder_dtype = dtype if encoder_dtype is None else encoder_dtype
        if self.encoder_dtype != dtype:
            for part in (self.vae.encoder, self.vae.quant_conv):
                if part is not None:
                    part.to(self.encoder_dtype)
        self.lcm_unet = None if lcm_unet is None else _prepare(lcm_unet, self.device, dtype)
        #: the distilled encoder of the conditioning channels (`x2video.model.channel_encoder`), or None:
        #: the VAE's encoder. Runs in `encoder_dtype` like the VAE encoder it replaces.
        self.channel_encoder = None if channel_encoder is None else _prepare(channel_encoder, self.device, self.encoder_dtype)
        if channel_encoder is not None and channel_encoder.factor != config.vae.downsample:
            raise ValueError(f"channel encoder has latent factor {channel_encoder.factor}, the VAE {config.vae.downsample}")
        if text_encoder is None and (config.text.kind == "minilm" or config.text.path):
            text_encoder = build_text_encoder(config.text.kind, config.text.max_length, config.unet.cross_attention_dim, config.text.path)
        self.text_encoder = text_encoder
        self.is_untrained = untrained
        self.encode_batch = encode_batch
        self.downsample = config.vae.downsample
        self.latent_channels = config.vae.latent_channels
        self.num_train_timesteps = config.num_train_timesteps
        self._content_key: str | None = None
        #: the tier-1 network (`x2video.model.residual`), or None; `from_pretrained` loads the folder's
        #: residual.safetensors. The Renderer runs it for frames with nothing to generate (`x2video.tiers.registry`).
        self.residual_net = None
        #: whether auto may render with `residual_net` (residual.json's 'auto': it beat the formula on the validation rooms)
        self.residual_auto = True
        #: tier 1's net fine-tuned for its difference over a shot's frames, or None; `from_pretrained` loads the folder's
        #: difference.safetensors. Only the residual tier's difference over the base runs it (`ResidualTier.glossy_frames`).
        self.difference_net = None
        #: what runs the UNet, the decoder and the channel encoder: 'torch', or an exported graph's runtime
        #: ('onnx', 'openvino'); see `set_engine` and `x2video.model.engine`
        self.engine = "torch"
        self._parts: dict[str, object] = {}  # runtime -> x2video.model.engine.CompiledParts, built on first use
        #: threads the engine's graphs run on (None: torch's thread count when they are first built); set before
        #: the first diffusion render. The editor gives them every core (x2video_app.render_controller).
        self.engine_threads: int | None = None
        if is_video_unet(unet) != config.video:
            raise ValueError(f"config says video={config.video} but the UNet has {unet.config.in_channels} input channels")

    # -- construction -------------------------------------------------------------
    @classmethod
    def untrained(cls, name: str | ModelConfig = "tiny", *, seed: int = 0, device: torch.device | str = "cpu", dtype: torch.dtype = torch.float32,
                  **overrides) -> "X2VideoModel":
        """UNTRAINED (randomly initialised) weights of a preset, for tests and demos: renders are noise."""
        cfg = preset(name, **overrides) if isinstance(name, str) else name
        with torch.random.fork_rng(devices=[]):
            torch.manual_seed(seed)
            unet, vae = build_unet(cfg), build_vae(cfg.vae)
        log.warning("X2VideoModel.untrained(%r): randomly initialised weights, output is not a render", cfg.name)
        return cls(cfg, unet, vae, device=device, dtype=dtype, untrained=True)

    @classmethod
    def from_pretrained(cls, directory: str | os.PathLike, *, device: torch.device | str = "cpu", dtype: torch.dtype = torch.float32,
                        text_encoder: TextEncoder | None = None, encoder_dtype: torch.dtype | None = None,
                        channel_encoder: str = DEFAULT_CHANNEL_ENCODER) -> "X2VideoModel":
        """Load a checkpoint directory written by `save_pretrained` (shapes validated by name).

        `encoder_dtype` (default: `dtype`) runs the VAE's encoder alone in another precision: bfloat16
        while everything else stays float32 (`--bf16-encoder`). Encoding the channels (four or five VAE
        passes per frame) is the same work for every sampler, the fixed cost per frame that bounds
        LCM-2's speed-up, and a convolution stack that gains most from bf16 on CPUs with native bf16
        (AVX512-BF16, AMX; on others bf16 is emulated and slower). The decoder stays in float32: decoding in
        bf16 too cost temporal consistency (docs/evaluations/).

        `channel_encoder` picks what encodes the conditioning channels: "vae" (the VAE's encoder, what
        the UNet was trained on) or "distilled" (the folder's `channel_encoder.safetensors`: the same
        encoder without its mid-block attention, trained to reproduce the full encoder's latents; see
        `x2video.model.channel_encoder`). "auto": the distilled one when the folder has it."""
        directory = Path(directory)
        cfg = read_config(directory)
        unet, vae = build_unet(cfg), build_vae(cfg.vae)
        load_into(unet, directory / "unet.safetensors", "unet")
        load_into(vae, directory / "vae.safetensors", "vae")
        lcm = None
        if (directory / "lcm_unet.safetensors").is_file():
            lcm = build_unet(cfg)
            load_into(lcm, directory / "lcm_unet.safetensors", "lcm_unet")
        enc = None
        if channel_encoder not in CHANNEL_ENCODERS:
            raise ValueError(f"channel_encoder must be one of {CHANNEL_ENCODERS}, got {channel_encoder!r}")
        enc_file = directory / "channel_encoder.safetensors"
        if channel_encoder == "distilled" and not enc_file.is_file():
            raise FileNotFoundError(f"{enc_file} is missing: this model has no distilled channel encoder "
                                    f"(train one with `x2video train encoder --teacher {directory}`), or use --channel-encoder vae")
        if channel_encoder != "vae" and enc_file.is_file():
            enc = ChannelEncoder(cfg.vae)
            load_into(enc, enc_file, "channel_encoder")
            log.info("channels encoded by the distilled encoder %s (channel_encoder='vae': the full VAE encoder)", enc_file)
        model = cls(cfg, unet, vae, text_encoder, lcm, device=device, dtype=dtype, encoder_dtype=encoder_dtype, channel_encoder=enc)
        model._content_key = None
        if (directory / "residual.safetensors").is_file():
            import json

            from x2video.model.residual import load as load_residual
            from x2video.model.residual_engine import engine

            model.residual_net = engine(load_residual(directory, model.device), model.device)
            #: whether quality 'auto' may use it: residual.json's "auto", set when the net beat the formula on the validation rooms
            model.residual_auto = bool(json.loads((directory / "residual.json").read_text()).get("auto", False))
            if cfg.prior == "tier1":
                model._check_prior_net(directory)
            if (directory / "difference.safetensors").is_file():
                model.difference_net = engine(load_residual(directory, model.device, name="difference"), model.device)
        elif cfg.prior == "tier1":
            raise FileNotFoundError(f"{directory / 'residual.safetensors'} is missing: this model samples its residual over tier 1's "
                                    f"frame (config prior 'tier1'), so it needs the tier-1 net it was trained with beside its weights")
        return model

    def _check_prior_net(self, directory: Path) -> None:
        """Warn when the tier-1 net beside a tier-1-prior model is not the one its training latents were made with (the
        `prior_net` its training.json records): the sampler then starts from frames it was not trained over."""
        import json

        from x2video.model.residual_engine import weights_sha

        doc = directory / "training.json"
        want = json.loads(doc.read_text()).get("shipped", {}).get("model", {}).get("prior_net") if doc.is_file() else None
        if want and want != (got := weights_sha(self.residual_net)):
            log.warning("%s: the tier-1 net beside the weights (sha %s) is not the one the diffusion model was trained over "
                        "(sha %s, training.json): the diffusion tier samples its residual over another net's frames; ship both "
                        "together", directory, got, want)

    def save_pretrained(self, directory: str | os.PathLike, *, dtype: torch.dtype = torch.float32) -> Path:
        """Write config.json + unet/vae[/lcm_unet].safetensors (fp32, bf16 or fp16) into `directory`."""
        modules = {"unet": self.unet, "vae": self.vae}
        if self.lcm_unet is not None:
            modules["lcm_unet"] = self.lcm_unet
        if self.channel_encoder is not None:
            modules["channel_encoder"] = self.channel_encoder
        assert set(modules) <= set(PARTS)
        return save_checkpoint(directory, self.config, modules, dtype)

    def to_video(self, shading_prior: bool | None = None) -> "X2VideoModel":
        """A video model converted from this image model (new inputs zero, alphas 0, same VAE and text encoder)."""
        if self.config.video:
            raise ValueError("model is already a video model")
        sp = self.config.shading_prior if shading_prior is None else shading_prior
        cfg = copy.deepcopy(self.config)
        cfg.video, cfg.shading_prior = True, sp
        unet = convert_image_to_video(self.unet, cfg.hybrid, sp)
        return X2VideoModel(cfg, unet, self.vae, self.text_encoder, device=self.device, dtype=self.dtype, untrained=self.is_untrained,
                            encoder_dtype=self.encoder_dtype, channel_encoder=self.channel_encoder)

    # -- engine --------------------------------------------------------------------
    def set_engine(self, engine: str) -> str:
        """Choose what runs the UNet, the VAE decoder and the channel encoder (`RenderSettings.engine`:
        'torch', 'onnx', 'openvino' or 'auto'; `x2video.model.engine`) and return the runtime chosen.
        Graphs are exported on first use per window and frame size; PyTorch stays the reference."""
        from x2video.model.engine import resolve

        runtime = resolve(engine, self.device, self.dtype, untrained=self.is_untrained)
        if runtime != self.engine:
            log.info("engine %s: UNet, VAE decoder and channel encoder run on %s", engine, runtime)
        self.engine = runtime
        return runtime

    def _compiled(self):
        """The `CompiledParts` of the current engine, or None for PyTorch."""
        if self.engine == "torch":
            return None
        parts = self._parts.get(self.engine)
        if parts is None:
            from x2video.model.engine import CompiledParts

            parts = self._parts[self.engine] = CompiledParts(self, self.engine, threads=self.engine_threads)
        return parts

    # -- RenderModel ---------------------------------------------------------------
    @property
    def has_lcm(self) -> bool:
        return self.lcm_unet is not None

    @property
    def residual_prior(self) -> bool:
        """Whether the UNet samples the residual over the shading prior's latent (`ModelConfig.residual_prior`)."""
        return bool(self.config.shading_prior and self.config.residual_prior)

    @property
    def cond_channels(self) -> int:
        return cond_channels(self.config.shading_prior)

    def alphas_cumprod(self) -> torch.Tensor:
        return sd_alphas_cumprod(self.config.num_train_timesteps, self.config.beta_start, self.config.beta_end)

    def content_key(self) -> str:
        """sha256 of the config and the VAE weights (what `encode_frames` depends on); computed once.
        Call `reset_content_key()` after changing VAE weights or latent scales in place."""
        if self._content_key is None:
            h = hashlib.sha256(self.config.to_json().encode())
            h.update(str(self.encoder_dtype).encode())  # a bf16 encoder gives other latents
            parts = [("", self.vae)] + ([("channel_encoder.", self.channel_encoder)] if self.channel_encoder is not None else [])
            if self.config.prior == "tier1":  # the prior slot holds the tier-1 net's frame: its weights shape the latents
                from x2video.model.residual_engine import torch_module

                if self.residual_net is None:
                    raise ValueError("this model samples its residual over tier 1's frame (config prior 'tier1') and has no tier-1 net")
                parts.append(("residual.", torch_module(self.residual_net)))
            for prefix, module in parts:  # the distilled channel encoder gives other latents than the VAE
                for k, v in sorted(module.state_dict().items()):
                    h.update((prefix + k).encode())
                    h.update(v.detach().to("cpu", torch.float32).contiguous().numpy().tobytes())
            self._content_key = ("untrained-" if self.is_untrained else "") + h.hexdigest()[:32]
        return self._content_key

    def reset_content_key(self) -> None:
        self._content_key = None

    @torch.no_grad()
    def encode_image(self, rgb_linear: np.ndarray) -> torch.Tensor:
        rgb = np.asarray(rgb_linear, np.float32)
        if rgb.ndim != 3 or rgb.shape[-1] != 3:
            raise ValueError(f"encode_image: expected an (H, W, 3) image, got shape {rgb.shape}")
        if rgb.shape[0] % self.downsample or rgb.shape[1] % self.downsample:
            raise ValueError(f"encode_image: size {rgb.shape[0]}x{rgb.shape[1]} is not a multiple of {self.downsample}")
        return self._encode([to_vae_range("rgb", rgb)])[0] * self.config.latent_scales["rgb"]  # (4, h, w)

    def encode_prompts(self, prompts: Sequence[str]) -> torch.Tensor:
        if self.text_encoder is None:
            raise ValueError(f"model {self.config.name!r} has no text encoder (config.text.path is empty)")
        return self.text_encoder.encode(list(prompts)).to(self.device, self.dtype)  # (P, L, D)

    @torch.no_grad()
    def predict_v(self, x_t: torch.Tensor, t: torch.Tensor, window: WindowInputs, *, lcm: bool = False) -> torch.Tensor:
        unet = self.unet
        if lcm:
            if self.lcm_unet is None:
                raise ValueError("sampler 'lcm' needs distilled weights; this model has no lcm_unet.safetensors")
            unet = self.lcm_unet
        parts = self._compiled()
        if parts is not None:
            v = parts.unet(x_t, t, window, lcm=lcm)
            if v is not None:
                return v.to(self.device, self.dtype)
        n = x_t.shape[0]
        dev, dt = self.device, self.dtype
        has_local = window.text_local.shape[0] > 0
        return run_unet(
            unet,
            x_t.to(dev, dt),
            torch.as_tensor(t, device=dev),
            window.cond.to(dev, dt),
            window.ref.to(dev, dt),
            num_frames=n,
            text_global=window.text_global.to(dev, dt),
            ref_positions=window.ref_positions,
            mode=window.mode,
            level=window.level,
            text_local=window.text_local.to(dev, dt)[None] if has_local else None,  # (1, P, L, D)
            local_masks=window.local_masks.to(dev, dt) if has_local else None,  # (N, P, H, W)
            prediction=self.config.prediction,
        )

    def sample_to_latents(self, x0: torch.Tensor, cond: torch.Tensor) -> torch.Tensor:
        """RGB latents (N, 4, h, w) of a window from the sampler's output: the sample itself, or for a
        residual model the sample plus the shading prior's latent in `cond` (N, C_cond, h, w)."""
        if not self.residual_prior:
            return x0
        return x0 + prior_latents(cond.to(x0.device, x0.dtype))

    @torch.no_grad()
    def detail(self, frames: Sequence[FrameConditioning], cond: torch.Tensor) -> np.ndarray | None:
        """(N, H, W, 3) fine detail of the classical shading that the VAE loses, to add to the decoded
        frames of a residual model: shading - decode(z_shading), zero where the frame has no prior
        (albedo or irradiance dropped) and inside the A|M|R mask. None for other models."""
        if not self.residual_prior:
            return None
        if len(frames) != cond.shape[0]:
            raise ValueError(f"detail: {len(frames)} frames but {cond.shape[0]} conditioning latents")
        H, W = frames[0].size
        out = np.zeros((len(frames), H, W, 3), np.float32)
        idx = [i for i, fr in enumerate(frames) if shading_available(fr.channels)]
        if idx:
            smooth = self.decode(prior_latents(cond[idx]))  # (n, H, W, 3) what the VAE keeps of the shading
            for j, i in enumerate(idx):
                keep = (np.asarray(frames[i].amr_mask, np.float32) <= 0.5)[..., None]
                out[i] = (self.prior_image(frames[i]) - smooth[j]) * keep
        return out

    @torch.no_grad()
    def decode(self, latents: torch.Tensor) -> np.ndarray:
        z = latents.to(self.device, self.dtype) / self.config.latent_scales["rgb"]  # (N, 4, h, w)
        parts = self._compiled()

        def decoded(zi: torch.Tensor) -> torch.Tensor:  # (n, 3, H, W) in the VAE's range
            return self.vae.decode(zi).sample if parts is None else parts.decode(zi)

        out = [from_vae_range_rgb(decoded(z[i : i + self.encode_batch])) for i in range(0, z.shape[0], self.encode_batch)]
        return torch.cat(out).cpu().numpy().astype(np.float32)  # (N, H, W, 3) linear

    # -- helpers ------------------------------------------------------------------------
    def _encode(self, images: list[np.ndarray]) -> torch.Tensor:
        """(H, W, 3) arrays in [-1, 1] -> (n, 4, h, w) unscaled posterior-mode latents."""
        z = encode_mode(self.vae, images_to_tensor(images, self.device, self.encoder_dtype), self.encode_batch)
        return z.to(self.dtype)

    @torch.no_grad()
    def _encode_channels(self, images: list[np.ndarray]) -> torch.Tensor:
        """Like `_encode`, through the distilled channel encoder when the model has one (on the engine's graph
        when it runs one)."""
        parts = self._compiled()
        if parts is not None:
            x = images_to_tensor(images, self.device, torch.float32)
            zs = [parts.encode(x[i : i + self.encode_batch]) for i in range(0, x.shape[0], self.encode_batch)]
            if all(z is not None for z in zs):
                return torch.cat(zs).to(self.device, self.dtype)  # type: ignore[arg-type]
        if self.channel_encoder is None:
            return self._encode(images)
        x = images_to_tensor(images, self.device, self.encoder_dtype)
        b = self.encode_batch
        return torch.cat([self.channel_encoder(x[i : i + b]) for i in range(0, x.shape[0], b)]).to(self.dtype)
