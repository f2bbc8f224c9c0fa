"""Tier 1 of "no more model than a scene needs": one deterministic network pass for what the formula misses.

The formula albedo x irradiance is exact for diffuse light; what a path tracer adds is mostly
the glossy term (reflections, metals, mirrors), emitters and windows (docs/ARCHITECTURE.md, "Path-traced
ground truth"). `ResidualNet` predicts that remainder in log space from the five channels, at
full resolution, in one pass:

    y      = log1p(albedo x irradiance) + net(features)   (N, 3, H, W), exposure-normalised units
    output = expm1(y)                                      linear radiance, >= 0

The base is the plain product, not `x2video.model.shading.classical_shading`: its grey-world GGX
term overshoots Cycles' energy-conserving Principled BSDF (on a path-traced test room: 20.9 dB
against the product's 31.7 dB), so the net learns the specular term from the channels instead.
A small pixel-space U-Net (four levels, a global-context vector at the bottom so the light's
colour and level reach every pixel), zero-initialised output, so an untrained net is the
formula. Deterministic and per frame: it cannot flicker more than its inputs.
"""
from __future__ import annotations

import functools
import json
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Callable, Mapping

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

from x2video.formula import finite, formula, frame_shape

#: input feature planes, in order (see `features`)
FEATURES = ("albedo3", "normal3", "roughness", "metallic", "log_irradiance3", "log_formula3", "present5", "geometry")
#: where log1p(formula) sits among the input planes (`features`); `apply`'s base
FORMULA_PLANES = slice(11, 14)
#: the present flags of the five channels (`x2video.channels.INTRINSIC` order) among the input planes
PRESENT_PLANES = slice(14, 19)
#: planes of a net without screen-space hints; a net with `ResidualConfig.hints` reads `screen_space.PLANES` after them
BASE_PLANES = 20


@dataclass
class ResidualConfig:
    """Shape of the tier-1 network; stored beside its weights so a checkpoint rebuilds itself."""

    #: feature channels per level, finest first (the net downsamples by 2 between levels)
    widths: tuple[int, ...] = (16, 32, 64, 128)
    #: input planes: 3 + 3 + 1 + 1 + 3 + 3 + 5 present flags + 1 geometry mask (+ the hint planes with `hints`)
    in_channels: int = BASE_PLANES
    #: whether the net reads the screen-space hints (`x2video.model.screen_space`: reflections marched through
    #: the depth channel, the split-sum specular colour, N.V and the reflected direction) after the base planes
    hints: bool = False

    def __post_init__(self) -> None:
        from x2video.model.screen_space import N_PLANES

        want = BASE_PLANES + (N_PLANES if self.hints else 0)
        if self.hints and self.in_channels == BASE_PLANES:  # ResidualConfig(hints=True): the planes follow
            self.in_channels = want
        if self.in_channels != want:
            raise ValueError(f"ResidualConfig: in_channels {self.in_channels} does not match hints={self.hints} ({want} planes)")

    @property
    def factor(self) -> int:
        """Frames are padded to a multiple of this (reflect) and cropped back."""
        return 2 ** (len(self.widths) - 1)


def _block(cin: int, cout: int) -> nn.Sequential:
    return nn.Sequential(nn.Conv2d(cin, cout, 3, padding=1), nn.SiLU(), nn.Conv2d(cout, cout, 3, padding=1), nn.SiLU())


class ResidualNet(nn.Module):
    """features (N, C_in, H, W) -> log-space residual (N, 3, H, W); H, W multiples of `cfg.factor`."""

    def __init__(self, cfg: ResidualConfig | None = None):
        super().__init__()
        self.cfg = cfg = cfg or ResidualConfig()
        w = cfg.widths
        self.down = nn.ModuleList([_block(cfg.in_channels, w[0])] + [_block(w[i - 1], w[i]) for i in range(1, len(w))])
        self.pool = nn.ModuleList([nn.Conv2d(w[i], w[i], 2, stride=2) for i in range(len(w) - 1)])
        self.context = nn.Linear(w[-1], w[-1])
        self.up = nn.ModuleList([_block(w[i + 1] + w[i], w[i]) for i in range(len(w) - 1)])
        self.out = nn.Conv2d(w[0], 3, 1)
        nn.init.zeros_(self.out.weight)
        nn.init.zeros_(self.out.bias)

    def encode(self, x: torch.Tensor) -> tuple[list[torch.Tensor], torch.Tensor]:
        """(skips, finest first; bottom features (N, C, H/factor, W/factor)) of features x."""
        skips = []
        for i, block in enumerate(self.down):
            x = block(x)
            if i < len(self.pool):
                skips.append(x)
                x = self.pool[i](x)
        return skips, x

    def bottom(self, x: torch.Tensor) -> torch.Tensor:
        """(N, C, H/factor, W/factor) bottom features: their mean over a frame gives its global context."""
        return self.encode(x)[1]

    def context_vector(self, mean: torch.Tensor) -> torch.Tensor:
        """(N, C) global context from the (N, C) mean of a frame's bottom features."""
        return self.context(mean)

    def decode(self, skips: list[torch.Tensor], x: torch.Tensor, g: torch.Tensor) -> torch.Tensor:
        """Log-space residual (N, 3, H, W) from `encode`'s skips and bottom features x with the global context g (N, C)."""
        x = x + g[:, :, None, None]
        for i in reversed(range(len(self.up))):
            x = F.interpolate(x, scale_factor=2, mode="bilinear", align_corners=False)
            x = self.up[i](torch.cat([x, skips[i]], 1))
        return self.out(x)

    def forward(self, x: torch.Tensor, g: torch.Tensor | None = None) -> torch.Tensor:
        """Log-space residual of features x; `g` (N, C): the global context, from x itself when None (a whole
        frame), given for a tile of a larger frame (`apply_tiled`) so that every tile sees the frame's light."""
        skips, x = self.encode(x)
        if g is None:
            g = self.context_vector(x.mean((2, 3)))  # (N, C) global context: the light's level and colour
        return self.decode(skips, x, g)

    def forward_part(self, x: torch.Tensor, others: torch.Tensor, cells: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(log-space residual (N, 3, h, w), the (N, C) sum of its bottom features) of features x that are a box of a
        larger frame on the factor grid: the frame's global context is the mean of `others` (N, C), the sum of the
        frame's bottom features outside the box, and the box's own, over the frame's `cells` (N, 1) bottom cells
        (`x2video.base.tier1`). One encoder pass: the context needs the box's bottom features first."""
        skips, b = self.encode(x)
        s = b.sum((2, 3))  # (N, C)
        return self.decode(skips, b, self.context_vector((others + s) / cells)), s


#: a metal smoother than this is a mirror: what it shows is a sharp image of elsewhere, not in its channels
MIRROR_ROUGHNESS = 0.1


def receptive_radius(cfg: ResidualConfig) -> tuple[int, int]:
    """(output, bottom) reach in pixels of a `ResidualNet` of `cfg`, global context aside: an output pixel depends on the
    features at most `output` pixels away either side (58 for the default four levels); the bottom cell over pixels
    [f*j, f*j + f) on those in [f*j - a, f*j + b], so a changed pixel and a box's edge meet in one cell's view only when
    they are less than `bottom` = a + b pixels apart (67). Exact: each 3x3 conv at scale s widens by s, each 2x2
    stride-2 pool by s on one side, each bilinear x2 upsampling to scale s by 2s and s (tests/test_base_tier1.py
    checks it against the gradient's support)."""
    n = len(cfg.widths)
    lo = hi = 0
    s = 1
    for i in range(n):  # the encoder: two 3x3 convs per level, a 2x2 stride-2 pool between levels
        lo, hi = lo + 2 * s, hi + 2 * s
        if i < n - 1:
            hi, s = hi + s, 2 * s
    bottom = lo + hi  # [f*j - lo, f*j + hi]: hi already holds the cell's own f - 1 pixels
    for _ in range(n - 1):  # the decoder: bilinear x2 (align_corners=False reads the coarse cells either side), two 3x3 convs
        s //= 2
        lo, hi = lo + 2 * s + 2 * s, hi + s + 2 * s
    return max(lo, hi), bottom


def unseen_light(ch: Mapping[str, np.ndarray | None], shape: tuple[int, int] | None = None) -> np.ndarray | None:
    """(H, W) bool: pixels whose channels say nothing of the light seen there: no geometry (sky, a backdrop through
    an open window), a surface neither lit diffusely nor metal (clear glass: a path tracer's diffuse passes are 0
    there, so what shows through it is not in the channels), or a mirror (a metal smoother than `MIRROR_ROUGHNESS`).
    None when normal or irradiance is missing.
    What the tier-1 net puts there is a guess learned from the training rooms (mostly daylight behind windows)."""
    nr, ir = ch.get("normal"), ch.get("irradiance")
    if nr is None or ir is None:
        return None
    n = finite(nr)[..., :3]
    geometry = np.einsum("...c,...c->...", n, n) > 0.25  # |n| > 0.5
    light = np.maximum(finite(ir), 0)
    if light.ndim == 3:  # the brightest component (an elementwise max: numpy's reduce over a short last axis is slow)
        light = functools.reduce(np.maximum, [light[..., c] for c in range(light.shape[-1])])
    level = float(light[geometry].mean()) if geometry.any() else 0.0
    me = ch.get("metallic")
    metal = (np.asarray(finite(me)).reshape(light.shape) >= 0.5) if me is not None else np.zeros(light.shape, bool)
    ro = ch.get("roughness")
    mirror = metal & (np.asarray(finite(ro)).reshape(light.shape) < MIRROR_ROUGHNESS) if ro is not None else np.zeros(light.shape, bool)
    return ~geometry | (geometry & (light <= 1e-3 * level) & ~metal) | (geometry & mirror)


def features(ch: Mapping[str, np.ndarray | None], shape: tuple[int, int] | None = None, *, hints: bool = False,
             depth: np.ndarray | None = None, fov_y_deg: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(C_in, H, W) network input and (3, H, W) linear formula (albedo x irradiance) of one frame's channels
    (memory convention, irradiance exposure-normalised). A dropped channel is zeros with its present flag 0;
    `shape` = (H, W) is needed only when every channel is dropped. Non-finite values count as 0 (one NaN
    would otherwise reach the net's global context and blank the whole frame); roughness and metallic are
    clamped to [0, 1]. With `hints`, the screen-space hint planes follow (`x2video.model.screen_space`), made
    with the frame's `depth` (H, W[, 1], or None: those planes are 0) and vertical field of view."""
    h, w = frame_shape(ch, shape)

    def get(name: str, n: int) -> tuple[np.ndarray, float]:
        v = ch.get(name)
        if v is None:
            return np.zeros((h, w, n), np.float32), 0.0
        v = finite(v)
        return (v if v.ndim == 3 else v[..., None])[..., :n], 1.0

    al, pa = get("albedo", 3)
    nr, pn = get("normal", 3)
    ro, pr = get("roughness", 1)
    me, pm = get("metallic", 1)
    ro, me = np.clip(ro, 0, 1), np.clip(me, 0, 1)  # their range, as the loaders and the sampler's to_vae_range clamp them
    ir, pi = get("irradiance", 3)
    shading = formula(ch, (h, w))
    x = np.empty((BASE_PLANES + (hint_count() if hints else 0), h, w), np.float32)  # plane by plane: no (H, W, C) intermediate
    for i, a in ((0, al), (3, nr), (6, ro), (7, me), (8, np.log1p(np.maximum(ir, 0))), (11, np.log1p(np.maximum(shading, 0)))):
        x[i:i + a.shape[-1]] = np.moveaxis(a, -1, 0)
    x[14:19] = np.array([pa, pn, pr, pm, pi], np.float32)[:, None, None]
    x[19] = (np.einsum("hwc,hwc->hw", nr, nr) > 0.25) if pn else 1.0  # geometry: |normal| > 0.5
    if hints:
        from x2video.model.screen_space import hint_planes

        dz = None if depth is None or not pn else finite(depth)
        x[BASE_PLANES:] = hint_planes(np.clip(al, 0, 1), nr, ro, me, shading, unseen_light(ch, (h, w)), dz, fov_y_deg)
    return x, np.ascontiguousarray(shading.transpose(2, 0, 1))


def hint_count() -> int:
    from x2video.model.screen_space import N_PLANES

    return N_PLANES


def view_args(net, depth: Callable[[], np.ndarray | None] | np.ndarray | None, fov_y_deg: float | None) -> dict:
    """`features`' keyword arguments for `net`: none for a net without hints; else the frame's depth (read here
    when given as a reader) and field of view."""
    if not net.cfg.hints:
        return {}
    return {"hints": True, "depth": depth() if callable(depth) else depth, "fov_y_deg": fov_y_deg}


def correction(net, x: torch.Tensor) -> torch.Tensor:
    """The net's log-space correction (N, 3, H, W) of the formula for features x of any size (reflect-padded to
    the net's factor, cropped back)."""
    h, w = x.shape[-2:]
    f = net.cfg.factor  # an OnnxResidual carries the same cfg
    ph, pw = (-h) % f, (-w) % f
    xp = F.pad(x, (0, pw, 0, ph), mode="reflect" if min(h, w) > max(ph, pw) else "replicate") if ph or pw else x
    return net(xp)[..., :h, :w]


def apply(net, x: torch.Tensor, shading: torch.Tensor) -> torch.Tensor:
    """Linear radiance (N, 3, H, W) from features and the formula (`features`' second output) of any size."""
    return torch.expm1(torch.log1p(shading.clamp_min(0)) + correction(net, x)).clamp_min(0)


#: tier 1 on larger frames runs in overlapping tiles (`apply_tiled`): core side of a tile in pixels, the context
#: each side of it (more than the net's reach, so a tile sees what the whole frame would), and the width of the
#: linear blend between neighbouring tiles. Multiples of the net's factor.
TILE, HALO, FEATHER = 768, 64, 16
#: most (padded) pixels the net runs on at once, frames in a batch together: the bound on its working memory
MAX_PIXELS = (TILE + 2 * HALO) ** 2


def needs_tiles(size: tuple[int, int], factor: int, max_pixels: int | None = None) -> bool:
    """Whether a frame of (H, W) pixels, padded to `factor`, is larger than one pass of the net may be
    (`max_pixels`, default `MAX_PIXELS`)."""
    h, w = size
    return (h + (-h) % factor) * (w + (-w) % factor) > (MAX_PIXELS if max_pixels is None else max_pixels)


@dataclass(frozen=True)
class Tile:
    """One tile of a (padded) frame: `box` (y0, y1, x0, x1) the pixels the net sees, `core` the pixels the
    tile owns (the cores partition the frame); both on the net's factor grid."""

    box: tuple[int, int, int, int]
    core: tuple[int, int, int, int]


def _edges(n: int, tile: int, factor: int) -> list[int]:
    k = -(-n // tile)
    return sorted({round(i * n / k / factor) * factor for i in range(k)} | {n})


def tile_grid(h: int, w: int, tile: int = TILE, halo: int = HALO, factor: int = 8) -> list[Tile]:
    """Tiles of an (h, w) frame (multiples of `factor`): cores of at most `tile` pixels a side, as even as the
    factor grid allows, each seen with `halo` pixels of context (clipped at the frame's edges)."""
    for name, v in (("h", h), ("w", w), ("tile", tile), ("halo", halo)):
        if v % factor or v < (factor if name != "halo" else 0):
            raise ValueError(f"tile_grid: {name}={v} is not a positive multiple of the net's factor {factor}")
    ys, xs = _edges(h, tile, factor), _edges(w, tile, factor)
    return [Tile((max(y0 - halo, 0), min(y1 + halo, h), max(x0 - halo, 0), min(x1 + halo, w)), (y0, y1, x0, x1))
            for y0, y1 in zip(ys, ys[1:]) for x0, x1 in zip(xs, xs[1:])]


def _ramp(lo: int, hi: int, c0: int, c1: int, n: int, feather: int) -> np.ndarray:
    """1-D blend weights over pixels [lo, hi) of a tile whose core is [c0, c1) on an axis of n pixels: 1 in the
    core, linear ramps of `feather` pixels centred on core edges that have a neighbour (neighbours' ramps sum to 1)."""
    t = np.arange(lo, hi, dtype=np.float32) + 0.5
    wgt = np.ones(hi - lo, np.float32)
    if c0 > 0:
        wgt *= np.clip((t - (c0 - feather / 2)) / feather, 0, 1) if feather else (t >= c0)
    if c1 < n:
        wgt *= np.clip(((c1 + feather / 2) - t) / feather, 0, 1) if feather else (t < c1)
    return wgt


def _pad_channel(v: np.ndarray, ph: int, pw: int) -> np.ndarray:
    """Pad (H, W, ...) at the bottom/right as `apply` pads the features (reflect, edge where the frame is too small)."""
    if not ph and not pw:
        return v
    mode = "reflect" if min(v.shape[:2]) > max(ph, pw) else "edge"
    return np.pad(v, [(0, ph), (0, pw)] + [(0, 0)] * (v.ndim - 2), mode=mode)


def apply_tiled(net, ch: Mapping[str, np.ndarray | None], shape: tuple[int, int] | None = None, *, tile: int | None = None,
                halo: int | None = None, feather: int | None = None, depth: np.ndarray | None = None,
                fov_y_deg: float | None = None) -> np.ndarray:
    """(H, W, 3) linear radiance of one frame's channels: what `apply` gives for the whole frame, with the net run
    on overlapping tiles so that its working memory is bounded by a tile, whatever the frame's size.

    Two passes over the tiles: the first sums the net's bottom features over each tile's core, which gives the
    frame's global context exactly as a whole-frame pass computes it (`ResidualNet.forward`); the second runs the
    net on each tile with that context and blends neighbouring tiles over `feather` pixels. Features are made per
    tile from the channels, and the formula is applied at full resolution. With `halo` beyond the net's reach
    the result equals the whole-frame pass to float precision (`tests/test_bigframes.py` states the tolerance)."""
    tile, halo = TILE if tile is None else tile, HALO if halo is None else halo
    feather = min(FEATHER, 2 * halo) if feather is None else feather
    h, w = frame_shape(ch, shape)
    f = net.cfg.factor  # an OnnxResidual carries the same cfg
    if feather > 2 * halo:
        raise ValueError(f"apply_tiled: feather {feather} is wider than twice the halo {halo}")
    ph, pw = (-h) % f, (-w) % f
    padded = {k: None if v is None else _pad_channel(np.asarray(v), ph, pw) for k, v in ch.items()}
    H, W = h + ph, w + pw
    tiles = tile_grid(H, W, tile, halo, f)
    hints = None
    if net.cfg.hints:  # made on the whole frame (reflected rays cross tiles), padded as the channels are
        hints = features(ch, (h, w), hints=True, depth=depth, fov_y_deg=fov_y_deg)[0][BASE_PLANES:]
        hints = np.moveaxis(_pad_channel(np.moveaxis(hints, 0, -1), ph, pw), -1, 0)

    def tile_features(t: Tile) -> torch.Tensor:
        y0, y1, x0, x1 = t.box
        x, _ = features({k: None if v is None else v[y0:y1, x0:x1] for k, v in padded.items()}, (y1 - y0, x1 - x0))
        if hints is not None:
            x = np.concatenate([x, hints[:, y0:y1, x0:x1]])
        return torch.from_numpy(x)[None]  # (1, C_in, h_t, w_t)

    with torch.inference_mode():
        total = None
        for t in tiles:  # pass 1: the frame's mean bottom feature, from each tile's own cells
            (by0, _, bx0, _), (cy0, cy1, cx0, cx1) = t.box, t.core
            b = net.bottom(tile_features(t))[0, :, (cy0 - by0) // f:(cy1 - by0) // f, (cx0 - bx0) // f:(cx1 - bx0) // f]
            s = b.double().sum((1, 2))
            total = s if total is None else total + s
        assert total is not None
        g = net.context_vector((total / ((H // f) * (W // f))).float()[None])  # (1, C)
        delta = np.zeros((3, h, w), np.float32)
        weight = np.zeros((h, w), np.float32)
        for t in tiles:  # pass 2: the net on each tile with the frame's context, blended into the frame
            y0, y1, x0, x1 = t.box
            d = net(tile_features(t), g)[0].float().cpu().numpy()  # (3, h_t, w_t)
            cy0, cy1, cx0, cx1 = t.core
            wy, wx = _ramp(y0, y1, cy0, cy1, H, feather), _ramp(x0, x1, cx0, cx1, W, feather)
            ey, ex = min(y1, h) - y0, min(x1, w) - x0  # the padding is cropped
            if ey <= 0 or ex <= 0:
                continue
            wt = wy[:ey, None] * wx[None, :ex]
            delta[:, y0:y0 + ey, x0:x0 + ex] += d[:, :ey, :ex] * wt
            weight[y0:y0 + ey, x0:x0 + ex] += wt
    delta /= np.maximum(weight, 1e-12)
    base = formula(ch, (h, w))  # (h, w, 3), full resolution
    out = np.expm1(np.log1p(np.maximum(base, 0)) + delta.transpose(1, 2, 0))
    return np.maximum(out, 0).astype(np.float32)


def save(net: ResidualNet, folder: str | Path, extra: dict | None = None, name: str = "residual") -> Path:
    """fp16 `name`.safetensors + `name`.json (config and what trained it) in `folder`: "residual" (tier 1), or
    "difference" (the same net fine-tuned on edit pairs for its difference over a shot's frames, `x2video.train.difference_stage`)."""
    from safetensors.torch import save_file

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    from x2video.io.atomic import atomic_path, write_json_atomic

    with atomic_path(folder / f"{name}.safetensors") as tmp:
        save_file({k: v.detach().to(torch.float16).contiguous() for k, v in net.state_dict().items()}, str(tmp))
    cfg = asdict(net.cfg)
    write_json_atomic(folder / f"{name}.json", {"config": cfg, **(extra or {})})
    return folder / f"{name}.safetensors"


def load(folder: str | Path, device: str | torch.device = "cpu", name: str = "residual") -> ResidualNet:
    """The net saved in `folder` by `save` under `name` (float32 on `device`, eval mode)."""
    from safetensors.torch import load_file

    folder = Path(folder)
    meta = folder / f"{name}.json"
    if not meta.is_file():
        how = "x2video train difference" if name == "difference" else "x2video train residual"
        raise FileNotFoundError(f"{meta}: no tier-1 {name} network here (train one with `{how}`)")
    cfg = json.loads(meta.read_text())["config"]
    net = ResidualNet(ResidualConfig(widths=tuple(cfg["widths"]), in_channels=int(cfg["in_channels"]), hints=bool(cfg.get("hints", False))))
    state = load_file(str(folder / f"{name}.safetensors"))
    net.load_state_dict({k: v.float() for k, v in state.items()})
    return net.to(device).eval()
