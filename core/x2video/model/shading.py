"""The classical shading of intrinsic channels: the shading prior input (our addition) and the classical baseline.

    diffuse  = albedo * (1 - metallic) * irradiance
    specular = irradiance * (F0 * A + B),   F0 = mix(0.04, albedo, metallic)
    (A, B)   = Karis' analytic approximation of the split-sum GGX environment BRDF
               ("Physically Based Shading on Mobile", 2014) at (roughness, N.V)
    shading  = diffuse + specular   (linear RGB; display with `x2video.channels.tonemap`)

Conventions (docs/SHOT_FORMAT.md): irradiance is the diffuse-convention irradiance
(diffuse radiance = albedo x irradiance); normals are camera-space, +Z towards the viewer,
so the view direction is +Z and N.V = n_z. Irradiance stands in for the prefiltered
incoming radiance of the split sum (the channels carry no reflected-direction radiance),
so the specular term is a grey-world estimate: it brightens glossy and metallic surfaces
correctly on average but cannot draw reflections; that is left to the network.

Where a term cannot be computed: albedo or irradiance dropped -> all zeros; normal or
roughness dropped -> no specular term; metallic dropped -> metallic 0; pixels inside the
A|M|R mask (`amr_mask` > 0.5) -> zero.
"""
from __future__ import annotations

from typing import Mapping

import numpy as np

from x2video.channels import INTRINSIC

#: Karis' fitted constants for the analytic environment BRDF.
_C0 = np.array([-1.0, -0.0275, -0.572, 0.022], np.float32)
_C1 = np.array([1.0, 0.0425, 1.04, -0.04], np.float32)


def env_brdf_approx(roughness: np.ndarray, n_dot_v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Split-sum GGX environment BRDF scale A and bias B (Karis 2014), elementwise on (H, W) arrays.
    The fit dips slightly below zero (B ~ -0.002) for rough surfaces; both are clamped at 0."""
    r = roughness[..., None] * _C0 + _C1  # (H, W, 4)
    a004 = np.minimum(r[..., 0] * r[..., 0], np.exp2(-9.28 * n_dot_v)) * r[..., 0] + r[..., 1]
    a = a004 * -1.04 + r[..., 2]
    b = a004 * 1.04 + r[..., 3]
    return np.maximum(a, 0).astype(np.float32), np.maximum(b, 0).astype(np.float32)


def _one(x: np.ndarray | None) -> np.ndarray | None:
    """(H, W) from an (H, W) or (H, W, C) single-valued channel."""
    if x is None:
        return None
    x = np.asarray(x, np.float32)
    return x[..., 0] if x.ndim == 3 else x


def shading_available(channels: Mapping[str, np.ndarray | None]) -> bool:
    """Whether the shading is non-trivial: needs albedo and irradiance."""
    return channels.get("albedo") is not None and channels.get("irradiance") is not None


def classical_shading(channels: Mapping[str, np.ndarray | None], amr_mask: np.ndarray | None = None) -> np.ndarray:
    """Classical shading of one frame's channels (the memory convention of docs/ARCHITECTURE.md) -> (H, W, 3) linear RGB float32.

    `channels` maps albedo/normal/roughness/metallic/irradiance to arrays or None (dropped).
    All present channels must share one (H, W). See the module docstring for the model."""
    # non-finite values count as 0, as the loaders and the tiers make them (one NaN albedo pixel or Inf irradiance
    # pixel otherwise reaches the shading prior's latent and the residual model's detail)
    present = {k: np.where(np.isfinite(v), v, np.float32(0)) for k, v in
               ((k, np.asarray(v, np.float32)) for k, v in channels.items() if v is not None and k in _USED)}
    if not present and amr_mask is None:
        raise ValueError("classical_shading: no channels and no mask, cannot infer the frame size")
    sizes = {k: v.shape[:2] for k, v in present.items()}
    if amr_mask is not None:
        sizes["amr_mask"] = np.shape(amr_mask)[:2]
    if len(set(sizes.values())) > 1:
        raise ValueError(f"classical_shading: channel sizes differ: {sizes}")
    h, w = next(iter(sizes.values()))
    if "albedo" not in present or "irradiance" not in present:
        return np.zeros((h, w, 3), np.float32)

    albedo = np.clip(present["albedo"], 0, 1)  # (H, W, 3)
    irr = np.maximum(present["irradiance"], 0)  # (H, W, 3)
    metallic = np.clip(_one(present.get("metallic")), 0, 1) if "metallic" in present else np.zeros((h, w), np.float32)
    out = albedo * (1 - metallic[..., None]) * irr  # diffuse
    if "normal" in present and "roughness" in present:
        n = present["normal"]
        n_dot_v = np.clip(n[..., 2] / np.maximum(np.linalg.norm(n, axis=-1), 1e-6), 0, 1)  # view dir +Z
        a, b = env_brdf_approx(np.clip(_one(present["roughness"]), 0, 1), n_dot_v)
        f0 = 0.04 * (1 - metallic[..., None]) + albedo * metallic[..., None]  # (H, W, 3)
        spec = irr * (f0 * a[..., None] + b[..., None])
        # background pixels (zero normal) carry no surface, hence no specular
        spec = np.where((np.linalg.norm(n, axis=-1) > 1e-3)[..., None], spec, 0)
        out = out + spec
    if amr_mask is not None:
        out = out * (np.asarray(amr_mask, np.float32) <= 0.5)[..., None]
    return out.astype(np.float32)


_USED = INTRINSIC
