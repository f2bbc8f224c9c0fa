"""argparse types shared by the `x2video` subcommands and the benches (kept import-light: the heavy
modules load when an argument is parsed, not when a parser is built)."""
from __future__ import annotations

import argparse


def size_arg(text: str) -> tuple[int, int]:
    """argparse type: 'WxH' -> (width, height) by `x2video.train.data.parse_size`."""
    from x2video.train.data import parse_size

    try:
        return parse_size(text)
    except ValueError as e:
        raise argparse.ArgumentTypeError(str(e)) from e


#: help of `--bf16-encoder` (x2video render, x2video eval, the benches)
BF16_ENCODER_HELP = ("run the VAE encoder (the channel encoding, a per-frame cost every sampler pays) in bfloat16 and the "
                     "rest in float32: faster on CPUs with native bf16 (AVX512-BF16, AMX), slower on others")
#: help of `--channel-encoder` (x2video render, x2video eval, the benches)
CHANNEL_ENCODER_HELP = ("what encodes the conditioning channels: 'vae' (the VAE's encoder, what the UNet was trained on), "
                        "'distilled' (the model folder's channel_encoder.safetensors: the encoder without its mid-block "
                        "attention, trained to reproduce the full encoder's latents; `x2video train encoder`) or 'auto' "
                        "(distilled when the folder has one)")
#: help of `--noise` and `--noise-shared` (x2video render, x2video eval, the benches)
NOISE_HELP = ("seed the initial noise per 'window' or per 'frame' of the shot (a frame then has the same noise in every "
              "window that holds it; `RenderSettings.noise`)")
NOISE_SHARED_HELP = ("with --noise frame: the fraction of the noise's variance every frame shares, in [0, 1] (a mixed "
                     "noise prior; `RenderSettings.noise_shared`; ignored with --noise window)")
#: help of `--ref-dc` (x2video render, x2video eval, the benches)
REF_DC_HELP = ("interpolation windows: at every denoising step pull the generated frames' latent mean per channel "
               "(global colour and brightness) this fraction of the way to the linear interpolation of the two "
               "references' means, in [0, 1] (`RenderSettings.ref_dc`); 0 = off")
#: help of `--resample` (x2video render, x2video eval, the benches)
RESAMPLE_HELP = ("DDIM, windows with reference frames: take each denoising step but the first and last R times, "
                 "going back one step's noise in between (RePaint's resampling; `RenderSettings.resample`); "
                 "1 = off (default), R costs those windows about R times the network passes; LCM ignores it")
#: help of `--max-levels` (x2video render, x2video eval, the benches)
MAX_LEVELS_HELP = ("recursive scheme: at most K levels (default: the fewest that let one keyframe window span the shot, "
                   "K = 3 at 65 frames); fewer put the keyframes (N-1)^(K-1) frames apart in chained keyframe windows "
                   "(`RenderSettings.max_levels`)")
#: help of `--seams/--no-seams` (x2video render, x2video eval, the benches)
SEAMS_HELP = ("recursive scheme, 18 frames or more at N = 5: after the first interpolation level, make each keyframe again "
              "with its neighbours in an interpolation window (the seam pass, `RenderSettings.seams`)")
