"""Screen-space hints for tier 1 (`x2video.model.residual`, nets with `ResidualConfig.hints`): what a glossy
surface reflects, and how much of it, from the frame's own channels, its depth and the camera's field of view.

- **Reflections** (screen-space ray marching): each surface pixel's view ray is mirrored about its normal and
  marched through the depth buffer; where it meets a surface the formula (albedo x irradiance, as edited) of
  that pixel is what a mirror there would show, where it meets a pixel whose channels hold no light (the sky
  through a window, glass: `residual.unseen_light`) the pixel reflects the outside. Rays that leave the
  screen say nothing. Needs depth; without it these planes are 0 and their present flag says so.
- **Specular colour**: F0 x A + B, with F0 = mix(0.04, albedo, metallic) and (A, B) the split-sum DFG terms
  for N.V and roughness (Karis' analytic fit of the table, "Physically Based Shading on Mobile", 2014): the
  colour and strength of the glossy lobe, which the net multiplies by the light it predicts.
- **View**: N.V and the reflected direction in camera space (the net is convolutional: without them it cannot
  tell where a pixel looks).

Camera space is OpenGL's (x right, y up, the camera looking down -z), as the channel convention's normals;
depth is the distance along -z (Blender's Depth pass), in any unit: the march is scaled by the frame's
median depth. A shot without a camera is taken to have `DEFAULT_FOV_Y_DEG`.
"""
from __future__ import annotations

import math

import numpy as np

#: vertical field of view assumed for a shot whose cameras are unknown (our generators' cameras)
DEFAULT_FOV_Y_DEG = 60.0
#: the hint planes, in order, as `hint_planes` makes them
PLANES = ("log_rel_depth", "depth_present", "n_dot_v", "reflect_x", "reflect_y", "reflect_z", "spec_r", "spec_g", "spec_b",
          "ssr_log_r", "ssr_log_g", "ssr_log_b", "ssr_hit", "ssr_outside")
N_PLANES = len(PLANES)
#: offsets of groups inside the hint planes
REFLECT_X = PLANES.index("reflect_x")
SSR_LOG = slice(PLANES.index("ssr_log_r"), PLANES.index("ssr_log_b") + 1)
#: ray-march samples per pixel, and the range of distances they cover as fractions of the frame's median depth
STEPS, NEAR, FAR = 24, 0.02, 3.0
#: how far behind the depth buffer (in median depths) a ray's sample must be to count as meeting a surface
BIAS = 0.005
#: depths beyond this many median depths are no depth (the background value renderers write)
FAR_OFF = 100.0
#: pixels marched at once (bounds the working memory on large frames)
CHUNK = 1 << 15


def view_dirs(h: int, w: int, fov_y_deg: float | None) -> np.ndarray:
    """(H, W, 3) unit vectors from the camera through each pixel's centre, camera space; and the focal length
    in pixels is `focal(h, fov_y_deg)`."""
    f = focal(h, fov_y_deg)
    v, u = np.mgrid[0:h, 0:w].astype(np.float32) + 0.5
    d = np.stack([(u - w / 2) / f, -(v - h / 2) / f, -np.ones_like(u)], -1)
    return (d / np.linalg.norm(d, axis=-1, keepdims=True)).astype(np.float32)


def focal(h: int, fov_y_deg: float | None) -> float:
    fov = math.radians(DEFAULT_FOV_Y_DEG if fov_y_deg is None else float(fov_y_deg))
    if not 0 < fov < math.pi:
        raise ValueError(f"field of view {math.degrees(fov):g} degrees: expected between 0 and 180")
    return h / 2 / math.tan(fov / 2)


def specular_colour(albedo: np.ndarray, metallic: np.ndarray, roughness: np.ndarray, ndv: np.ndarray) -> np.ndarray:
    """(H, W, 3) F0 x A + B of the split-sum approximation (Karis' analytic fit of the DFG table)."""
    m = metallic[..., None]
    f0 = 0.04 * (1 - m) + albedo * m
    r = roughness[..., None]
    c0 = np.array([-1.0, -0.0275, -0.572, 0.022], np.float32)
    c1 = np.array([1.0, 0.0425, 1.04, -0.04], np.float32)
    rr = r * c0 + c1  # (H, W, 4)
    a004 = np.minimum(rr[..., 0] * rr[..., 0], np.exp2(-9.28 * np.clip(ndv, 0, 1))) * rr[..., 0] + rr[..., 1]
    a = -1.04 * a004 + rr[..., 2]
    b = 1.04 * a004 + rr[..., 3]
    return (f0 * a[..., None] + b[..., None]).astype(np.float32)


def reflections(formula: np.ndarray, depth: np.ndarray, normal: np.ndarray, geometry: np.ndarray, unseen: np.ndarray,
                fov_y_deg: float | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Screen-space reflections: ((H, W, 3) log1p of the formula where each pixel's mirrored view ray first meets
    a surface, (H, W) 1 where it met one, (H, W) 1 where it met a pixel whose channels hold no light (`unseen`:
    sky, glass), i.e. the pixel reflects the outside). Zeros where the ray left the screen or the pixel has no
    geometry. `depth` (H, W) along -z, any unit; `geometry` and `unseen` (H, W) bool."""
    h, w = depth.shape
    colour = np.zeros((h, w, 3), np.float32)
    hit = np.zeros((h, w), np.float32)
    out = np.zeros((h, w), np.float32)
    ok = geometry & np.isfinite(depth) & (depth > 0)
    if not ok.any():
        return colour, hit, out
    med = float(np.median(depth[ok]))
    ok &= depth < FAR_OFF * med  # a renderer's "no hit" depth (Cycles writes 1e10 behind glass and sky)
    f = focal(h, fov_y_deg)
    d = view_dirs(h, w, fov_y_deg)
    n = normal / np.maximum(np.linalg.norm(normal, axis=-1, keepdims=True), 1e-6)
    r = d - 2 * np.sum(d * n, -1, keepdims=True) * n
    p = d / np.maximum(-d[..., 2:3], 1e-6) * depth[..., None]  # camera-space points (z = -depth)
    scene = np.where(ok, depth, np.inf).astype(np.float32)  # rays pass behind what has no depth
    lf = np.log1p(np.maximum(formula, 0)).astype(np.float32)
    ts = (med * NEAR * (FAR / NEAR) ** (np.arange(STEPS, dtype=np.float32) / (STEPS - 1))).astype(np.float32)
    thick = (0.05 * med + np.diff(ts, prepend=0.0) * 1.5).astype(np.float32)
    ys, xs = np.nonzero(ok)
    for s in range(0, len(ys), CHUNK):
        yi, xi = ys[s:s + CHUNK], xs[s:s + CHUNK]
        q = p[yi, xi][:, None, :] + r[yi, xi][:, None, :] * ts[None, :, None]  # (n, K, 3)
        z = -q[..., 2]
        front = z > 1e-3 * med
        zz = np.where(front, z, 1.0)
        u = f * q[..., 0] / zz + w / 2
        v = -f * q[..., 1] / zz + h / 2
        inside = front & (u >= 0) & (u < w) & (v >= 0) & (v < h)
        ui = np.clip(u, 0, w - 1).astype(np.int32)
        vi = np.clip(v, 0, h - 1).astype(np.int32)
        zs = scene[vi, ui]
        away = (np.abs(ui - xi[:, None]) + np.abs(vi - yi[:, None])) >= 2  # a ray's first samples fall on its own surface
        meets = inside & away & (((z > zs + BIAS * med) & (z - zs < thick[None, :])) | ~ok[vi, ui])
        first = np.argmax(meets, axis=1)
        any_ = meets[np.arange(len(yi)), first]
        hy, hx = vi[np.arange(len(yi)), first], ui[np.arange(len(yi)), first]
        outside = any_ & (unseen[hy, hx] | ~ok[hy, hx])
        surf = any_ & ~outside
        colour[yi[surf], xi[surf]] = lf[hy[surf], hx[surf]]
        hit[yi[surf], xi[surf]] = 1
        out[yi[outside], xi[outside]] = 1
    return colour, hit, out


def hint_planes(albedo: np.ndarray, normal: np.ndarray, roughness: np.ndarray, metallic: np.ndarray, formula: np.ndarray,
                unseen: np.ndarray | None, depth: np.ndarray | None, fov_y_deg: float | None) -> np.ndarray:
    """(N_PLANES, H, W) float32 hint planes (`PLANES`) of one frame; `depth` None: the depth-made planes are 0.
    Arrays in the channel convention: albedo, normal, formula (H, W, 3), roughness, metallic, depth (H, W) or (H, W, 1)."""
    h, w = normal.shape[:2]
    x = np.zeros((N_PLANES, h, w), np.float32)
    geometry = np.einsum("hwc,hwc->hw", normal, normal) > 0.25
    dirs = view_dirs(h, w, fov_y_deg)
    n = normal / np.maximum(np.linalg.norm(normal, axis=-1, keepdims=True), 1e-6)
    ndv = np.where(geometry, np.clip(-np.sum(dirs * n, -1), 0, 1), 0).astype(np.float32)
    refl = dirs - 2 * np.sum(dirs * n, -1, keepdims=True) * n
    x[2] = ndv
    x[3:6] = np.moveaxis(np.where(geometry[..., None], refl, 0), -1, 0)
    ro = roughness.reshape(h, w)
    me = metallic.reshape(h, w)
    x[6:9] = np.moveaxis(np.where(geometry[..., None], specular_colour(albedo, me, ro, ndv), 0), -1, 0)
    if depth is not None:
        dz = np.asarray(depth, np.float32).reshape(h, w)
        ok = geometry & np.isfinite(dz) & (dz > 0)
        if ok.any():
            med = float(np.median(dz[ok]))
            ok &= dz < FAR_OFF * med
            x[0] = np.where(ok, np.log(np.where(ok, dz, med) / med), 0)
            x[1] = 1.0
            col, hit, out = reflections(formula, dz, normal, geometry, unseen if unseen is not None else ~geometry, fov_y_deg)
            x[SSR_LOG] = np.moveaxis(col, -1, 0)
            x[12], x[13] = hit, out
    return x
