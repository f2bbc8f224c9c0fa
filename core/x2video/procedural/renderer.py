"""Headless moderngl PBR renderer of procedural rooms: every intrinsic channel, ids, depth and shaded HDR RGB per frame.

One pass writes all channels (multiple render targets). Per shot, once: cube shadow maps of the point lights (an atlas),
an orthographic sun shadow map, and a reflection probe at the room centre whose spherical-harmonics projection is the
indirect (ambient) irradiance and whose box-projected lookup gives reflections on glossy and metallic surfaces. The
probe also sets the exposure: all lights are scaled so the 90th percentile of the radiance reaches the mood's target.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from x2video.procedural.geometry import scene_vertices
from x2video.procedural.materials import PATTERNS
from x2video.procedural.scene import Scene
from x2video.procedural.shaders import CUBE_FACES, FRAGMENT, MAX_LIGHTS, MAX_OCCLUDERS, SHADOW_FRAGMENT, SHADOW_VERTEX, VERTEX
from x2video.shot import CameraPose

log = logging.getLogger(__name__)
LUMA = np.array([0.2126, 0.7152, 0.0722], np.float32)


@dataclass
class RenderConfig:
    """Quality knobs of the procedural renderer."""

    shadow_size: int = 512  #: texels per cube-shadow face
    sun_shadow_size: int = 1024
    probe_size: int = 96  #: texels per reflection-probe face
    #: bounces of indirect light estimated through the probe (0 = no ambient term)
    bounces: int = 2
    near: float = 0.05
    far: float = 40.0
    #: supersampling factor per axis for the shaded channels; ids and depth (hence motion) keep one sample per
    #: pixel, the pixel centre for odd factors (exact motion), a quarter pixel off for even ones
    ssaa: int = 1
    #: planar mirror reflection of the room in the floor (an extra pass per frame); off = probe reflections only
    planar: bool = True


def perspective(fov_y_deg: float, aspect: float, near: float, far: float) -> np.ndarray:
    """OpenGL projection matrix (4, 4)."""
    f = 1.0 / np.tan(np.radians(fov_y_deg) / 2)
    m = np.zeros((4, 4))
    m[0, 0], m[1, 1] = f / aspect, f
    m[2, 2], m[2, 3] = (far + near) / (near - far), 2 * far * near / (near - far)
    m[3, 2] = -1.0
    return m


def face_view(origin: np.ndarray, face: int) -> np.ndarray:
    """World-to-view (4, 4) of cube face `face` seen from `origin` (right/up/back rows from CUBE_FACES)."""
    f, r, u = (np.array(v, np.float64) for v in CUBE_FACES[face])
    m = np.eye(4)
    m[0, :3], m[1, :3], m[2, :3] = r, u, -f
    m[:3, 3] = -m[:3, :3] @ origin
    return m


def _gl(m: np.ndarray) -> bytes:
    """Row-major numpy (4, 4) or (3, 3) -> column-major float32 bytes for a GLSL uniform."""
    return np.asarray(m, np.float32).T.copy().tobytes()


def sh9_irradiance(faces: list[np.ndarray]) -> np.ndarray:
    """Irradiance SH coefficients (9, 3), convolved and divided by pi, from 6 cube faces of radiance (S, S, 3) in GL order.

    Face images are as read back from GL (row 0 = bottom = t of -1)."""
    s = faces[0].shape[0]
    c = (np.arange(s) + 0.5) / s * 2 - 1
    sc, tc = np.meshgrid(c, c)  # tc along rows (row 0 = -1)
    dw = 4.0 / s**2 / (1 + sc**2 + tc**2) ** 1.5  # solid angle per texel
    coef = np.zeros((9, 3))
    for i, img in enumerate(faces):
        f, r, u = (np.array(v, np.float64) for v in CUBE_FACES[i])
        d = f[None, None] + sc[..., None] * r + tc[..., None] * u
        d /= np.linalg.norm(d, axis=-1, keepdims=True)
        x, y, z = d[..., 0], d[..., 1], d[..., 2]
        basis = [0.282095 * np.ones_like(x), 0.488603 * y, 0.488603 * z, 0.488603 * x, 1.092548 * x * y,
                 1.092548 * y * z, 0.315392 * (3 * z * z - 1), 1.092548 * x * z, 0.546274 * (x * x - y * y)]
        for k, bk in enumerate(basis):
            coef[k] += np.einsum("hw,hwc->c", bk * dw, img.astype(np.float64))
    band = np.array([np.pi, 2 * np.pi / 3, 2 * np.pi / 3, 2 * np.pi / 3] + [np.pi / 4] * 5)
    return (coef * band[:, None] / np.pi).astype(np.float32)


class ProceduralRenderer:
    """Renders frames of one scene at a time: `set_scene(scene)`, then `render(pose)` per frame."""

    def __init__(self, width: int, height: int, cfg: RenderConfig | None = None):
        import moderngl

        if width < 8 or height < 8:
            raise ValueError(f"render size {width}x{height} too small (at least 8x8)")
        self.cfg = cfg or RenderConfig()
        self.width, self.height = width, height
        self.ctx = moderngl.create_standalone_context(backend="egl")
        self.prog = self.ctx.program(vertex_shader=VERTEX, fragment_shader=FRAGMENT)
        self.shadow_prog = self.ctx.program(vertex_shader=SHADOW_VERTEX, fragment_shader=SHADOW_FRAGMENT)
        self._fbos: dict[tuple[int, int], object] = {}
        s = self.cfg.shadow_size
        self.atlas = self.ctx.texture((6 * s, MAX_LIGHTS * s), 1, dtype="f4")
        self.atlas.filter = (moderngl.NEAREST, moderngl.NEAREST)
        self.atlas_fbo = self.ctx.framebuffer([self.atlas], self.ctx.depth_renderbuffer(self.atlas.size))
        ss = self.cfg.sun_shadow_size
        self.sun_map = self.ctx.texture((ss, ss), 1, dtype="f4")
        self.sun_map.filter = (moderngl.NEAREST, moderngl.NEAREST)
        self.sun_fbo = self.ctx.framebuffer([self.sun_map], self.ctx.depth_renderbuffer((ss, ss)))
        self.env = self.ctx.texture_cube((self.cfg.probe_size,) * 2, 3, dtype="f4")
        self.scene: Scene | None = None

    # ------------------------------------------------------------------ per scene
    def _fbo(self, w: int, h: int):
        key = (w, h)
        if key not in self._fbos:
            atts = [self.ctx.texture((w, h), 4, dtype="f4") for _ in range(4)]
            self._fbos[key] = self.ctx.framebuffer(atts, self.ctx.depth_renderbuffer((w, h)))
        return self._fbos[key]

    def set_scene(self, scene: Scene, exposure_poses: list[CameraPose] | None = None) -> None:
        """Upload geometry and materials, render shadow maps, build the probe and set the exposure (once per shot).

        The exposure scales every light so the 98th percentile of max(R, G, B) of the lit image (emission and
        sky excluded) meets the mood's target: measured on a few of `exposure_poses` (the shot's own path), or on
        the reflection probe when none are given."""
        import moderngl

        self.scene = scene
        verts = scene_vertices(scene.objects)
        for attr in ("vbo", "vao", "shadow_vao", "mat_tex"):
            if hasattr(self, attr):
                getattr(self, attr).release()
        self.vbo = self.ctx.buffer(verts.tobytes())
        self.vao = self.ctx.vertex_array(self.prog, [(self.vbo, "3f 3f 1f 1f 4x", "in_pos", "in_nrm", "in_mat", "in_id")])
        self.shadow_vao = self.ctx.vertex_array(self.shadow_prog, [(self.vbo, "3f 20x 1f", "in_pos", "in_shadow")])
        mats = np.zeros((len(scene.materials), 4, 4), np.float32)
        for i, m in enumerate(scene.materials):
            mats[i, 0] = [*m.albedo, PATTERNS.index(m.pattern)]
            mats[i, 1] = [m.roughness, m.metallic, m.scale, m.contrast]
            mats[i, 2] = [*m.emission, 1.0 if m.sky else 0.0]
        self.mat_tex = self.ctx.texture((4, len(scene.materials)), 4, mats.tobytes(), dtype="f4")
        self.mat_tex.filter = (moderngl.NEAREST, moderngl.NEAREST)

        lights = scene.lighting.points[:MAX_LIGHTS]
        if len(scene.lighting.points) > MAX_LIGHTS:
            log.warning("scene %d has %d point lights; rendering the first %d", scene.seed, len(scene.lighting.points), MAX_LIGHTS)
        self._render_point_shadows(lights)
        self._render_sun_shadow()
        self._lights = lights
        self._occluders = [o for o in scene.objects if o.blocks_camera][:MAX_OCCLUDERS]
        self._scale = 1.0
        self._sh = np.zeros((9, 3), np.float32)
        self._has_env = False
        probe = np.array([scene.width / 2, min(1.5, scene.height - 0.5), scene.depth / 2])
        self._probe = probe
        # indirect light: each probe render sees the previous estimate, so k renders give k bounces (lights only)
        faces = self._render_probe(probe, emission=0.0)
        for _ in range(self.cfg.bounces):
            self._sh = sh9_irradiance([f[0] for f in faces])
            faces = self._render_probe(probe, emission=0.0)
        if exposure_poses:
            views = [self._render_view(exposure_poses[i], 96) for i in sorted({0, len(exposure_poses) // 2, len(exposure_poses) - 1})]
        else:
            views = faces
        peak = np.concatenate([f[0].max(-1)[f[1] > 0] for f in views])
        p98 = float(np.percentile(peak, 98)) if peak.size else 0.0
        self._scale = scene.lighting.target / p98 if p98 > 1e-6 else 1.0
        scene.lighting.exposure = self._scale
        self._sh = self._sh * self._scale
        # the reflection probe, now with glowing lamps and the sky, which also add to the ambient term
        faces = self._render_probe(probe, emission=1.0)
        if self.cfg.bounces > 0:
            self._sh = sh9_irradiance([f[0] for f in faces])
        for i, (rgb, _) in enumerate(faces):
            self.env.write(i, np.ascontiguousarray(rgb, np.float32).tobytes())
        self.env.build_mipmaps()
        self.env.filter = (moderngl.LINEAR_MIPMAP_LINEAR, moderngl.LINEAR)
        self._has_env = True

    def _draw_shadow(self, vp: np.ndarray, origin: np.ndarray, axis: np.ndarray, ortho: bool) -> None:
        self.shadow_prog["u_viewproj"].write(_gl(vp))
        self.shadow_prog["u_origin"].value = tuple(map(float, origin))
        self.shadow_prog["u_axis"].value = tuple(map(float, axis))
        self.shadow_prog["u_ortho"].value = 1 if ortho else 0
        self.shadow_vao.render()

    def _render_point_shadows(self, lights) -> None:
        s = self.cfg.shadow_size
        self.atlas_fbo.use()
        self.ctx.disable(self.ctx.CULL_FACE)
        self.ctx.enable(self.ctx.DEPTH_TEST)
        self.atlas_fbo.clear(1e9, 1e9, 1e9, 1e9, depth=1.0)
        proj = perspective(90.0, 1.0, 0.02, self.cfg.far)
        for i, light in enumerate(lights):
            for face in range(6):
                self.atlas_fbo.viewport = (face * s, i * s, s, s)
                self._draw_shadow(proj @ face_view(light.position, face), light.position, np.zeros(3), False)

    def _render_sun_shadow(self) -> None:
        sc = self.scene
        self.sun_fbo.use()
        self.sun_fbo.clear(1e9, 1e9, 1e9, 1e9, depth=1.0)
        self._sun_vp = np.eye(4)
        self._sun_origin = np.zeros(3)
        if sc.lighting.sun is None:
            return
        d = sc.lighting.sun.direction
        centre = np.array([sc.width / 2, sc.height / 2, sc.depth / 2])
        radius = 0.5 * np.linalg.norm([sc.width + 1, sc.height + 1, sc.depth + 1])
        origin = centre + d * (radius + 1.0)
        f = -d
        r = np.cross(f, [0.0, 1.0, 0.0]) if abs(f[1]) < 0.99 else np.array([1.0, 0, 0])
        r /= np.linalg.norm(r)
        u = np.cross(r, f)
        view = np.eye(4)
        view[0, :3], view[1, :3], view[2, :3] = r, u, -f
        view[:3, 3] = -view[:3, :3] @ origin
        far = 2 * radius + 2.0
        ortho = np.diag([1 / radius, 1 / radius, -2 / far, 1.0])
        ortho[2, 3] = -1.0
        self._sun_vp, self._sun_origin = ortho @ view, origin
        self.sun_fbo.viewport = (0, 0, *self.sun_map.size)
        self._draw_shadow(self._sun_vp, origin, f, True)

    def _set_uniforms(self, view: np.ndarray, campos: np.ndarray, emission: float, planar: bool, mirror: bool) -> None:
        p, sc = self.prog, self.scene
        p["u_has_planar"].value = 1 if planar else 0
        p["u_clip_floor"].value = 1 if mirror else 0
        p["u_view"].write(_gl(view))
        p["u_viewrot"].write(_gl(view[:3, :3]))
        p["u_campos"].value = tuple(map(float, campos))
        lights = self._lights
        n = len(lights)
        pad = lambda a, k: np.concatenate([np.asarray(a, np.float32).reshape(n, k), np.zeros((MAX_LIGHTS - n, k), np.float32)])  # noqa: E731
        p["u_nl"].value = n
        if n:
            p["u_lpos"].write(pad([lt.position for lt in lights], 3).tobytes())
            p["u_lcol"].write(pad([lt.colour * lt.intensity * self._scale for lt in lights], 3).tobytes())
            p["u_lrad2"].write(pad([lt.radius**2 for lt in lights], 1).tobytes())
            p["u_ldir"].write(pad([[*(lt.direction if lt.direction is not None else np.zeros(3)), 1.0 if lt.direction is not None else 0.0]
                                   for lt in lights], 4).tobytes())
        sun = sc.lighting.sun
        p["u_has_sun"].value = 1 if sun is not None else 0
        if sun is not None:
            p["u_sun_dir"].value = tuple(map(float, sun.direction))
            p["u_sun_col"].value = tuple(map(float, sun.colour * sun.intensity * self._scale))
            p["u_sun_vp"].write(_gl(self._sun_vp))
            p["u_sun_origin"].value = tuple(map(float, self._sun_origin))
        p["u_sh"].write(np.asarray(self._sh, np.float32).tobytes())
        occ = self._occluders
        p["u_nocc"].value = len(occ)
        if occ:
            pad3 = lambda a: np.concatenate([np.asarray(a, np.float32).reshape(-1, 3), np.zeros((MAX_OCCLUDERS - len(occ), 3), np.float32)])  # noqa: E731
            p["u_occ_lo"].write(pad3([o.lo for o in occ]).tobytes())
            p["u_occ_hi"].write(pad3([o.hi for o in occ]).tobytes())
            p["u_occ_id"].write(np.array([o.id for o in occ] + [0] * (MAX_OCCLUDERS - len(occ)), np.int32).tobytes())
        p["u_has_env"].value = 1 if self._has_env else 0
        p["u_probe"].value = tuple(map(float, self._probe))
        p["u_box_lo"].value = (0.0, 0.0, 0.0)
        p["u_box_hi"].value = (float(sc.width), float(sc.height), float(sc.depth))
        p["u_env_mips"].value = float(np.log2(self.cfg.probe_size))
        p["u_emission_scale"].value = float(emission)
        p["u_shadow_size"].value = self.cfg.shadow_size
        self.mat_tex.use(0)
        self.atlas.use(1)
        self.sun_map.use(2)
        self.env.use(3)
        p["u_materials"].value, p["u_shadow_atlas"].value, p["u_sun_map"].value, p["u_env"].value = 0, 1, 2, 3
        if planar:
            self._planar_fbo.color_attachments[0].use(4)
            p["u_planar"].value = 4
            p["u_planar_mips"].value = float(np.log2(max(self._planar_fbo.size)))

    def _draw(self, fbo, viewproj: np.ndarray, view: np.ndarray, campos: np.ndarray, emission: float, cull: bool,
              planar: bool = False, mirror: bool = False, read: bool = True) -> list[np.ndarray]:
        fbo.use()
        fbo.viewport = (0, 0, *fbo.size)
        self.ctx.enable(self.ctx.DEPTH_TEST)
        if cull:
            self.ctx.enable(self.ctx.CULL_FACE)
        else:
            self.ctx.disable(self.ctx.CULL_FACE)
        self.ctx.front_face = "cw" if mirror else "ccw"  # a mirror image flips the winding
        fbo.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
        self._set_uniforms(view, campos, emission, planar, mirror)
        self.prog["u_viewproj"].write(_gl(viewproj))
        self.vao.render()
        self.ctx.front_face = "ccw"
        if not read:
            return []
        w, h = fbo.size
        return [np.frombuffer(fbo.read(components=4, attachment=i, dtype="f4"), np.float32).reshape(h, w, 4) for i in range(4)]

    def _render_mirror(self, view: np.ndarray, proj: np.ndarray, campos: np.ndarray, w: int, h: int) -> None:
        """Render the room mirrored in the floor plane y = 0 into the planar-reflection texture (with mipmaps)."""
        import moderngl

        if getattr(self, "_planar_fbo", None) is None or self._planar_fbo.size != (w, h):
            tex = self.ctx.texture((w, h), 4, dtype="f4")
            self._planar_fbo = self.ctx.framebuffer([tex], self.ctx.depth_renderbuffer((w, h)))
        mirror = np.diag([1.0, -1.0, 1.0, 1.0])
        view_m = view @ mirror
        self._draw(self._planar_fbo, proj @ view_m, view_m, mirror[:3, :3] @ campos, 1.0, cull=True, mirror=True, read=False)
        tex = self._planar_fbo.color_attachments[0]
        tex.build_mipmaps()
        tex.filter = (moderngl.LINEAR_MIPMAP_LINEAR, moderngl.LINEAR)

    def _render_probe(self, origin: np.ndarray, emission: float) -> list[tuple[np.ndarray, np.ndarray]]:
        """6 faces: (radiance (S, S, 3) as read back, object ids (S, S)) each."""
        s = self.cfg.probe_size
        fbo = self._fbo(s, s)
        proj = perspective(90.0, 1.0, self.cfg.near, self.cfg.far)
        out = []
        for face in range(6):
            view = face_view(origin, face)
            rgb, _, _, irr = self._draw(fbo, proj @ view, view, origin, emission, cull=False)
            out.append((np.nan_to_num(rgb[..., :3], nan=0.0, posinf=0.0), irr[..., 3].copy()))
        return out

    def _render_view(self, pose: CameraPose, width: int) -> tuple[np.ndarray, np.ndarray]:
        """A small render of a camera view without emission: (radiance (h, w, 3), ids (h, w))."""
        h = max(8, int(round(width * self.height / self.width)))
        c2w = np.asarray(pose.cam_to_world, np.float64)
        view = np.linalg.inv(c2w)
        proj = perspective(pose.fov_y_deg or 60.0, self.width / self.height, self.cfg.near, self.cfg.far)
        rgb, _, _, irr = self._draw(self._fbo(width, h), proj @ view, view, c2w[:3, 3], 0.0, cull=True)
        return np.nan_to_num(rgb[..., :3], nan=0.0, posinf=0.0), irr[..., 3]

    # ------------------------------------------------------------------ per frame
    def render(self, pose: CameraPose) -> dict[str, np.ndarray]:
        """All channels of one frame, rows top to bottom: rgb, albedo, normal, irradiance (H, W, 3); roughness,
        metallic, depth (H, W, 1) float32; ids (H, W, 1) int32."""
        if self.scene is None:
            raise RuntimeError("call set_scene(scene) before render(pose)")
        c2w = np.asarray(pose.cam_to_world, np.float64)
        view = np.linalg.inv(c2w)
        k = max(1, int(self.cfg.ssaa))
        proj = perspective(pose.fov_y_deg or 60.0, self.width / self.height, self.cfg.near, self.cfg.far)
        if self.cfg.planar:
            self._render_mirror(view, proj, c2w[:3, 3], self.width * k, self.height * k)
        rgb, alb, nrm, irr = (a[::-1] for a in self._draw(self._fbo(self.width * k, self.height * k), proj @ view, view, c2w[:3, 3], 1.0,
                                                          cull=True, planar=self.cfg.planar))
        if k > 1:  # box-filter the shaded channels; ids and depth keep the sample nearest the pixel centre
            h, w = self.height, self.width
            pick = lambda a: a[k // 2::k, k // 2::k]  # noqa: E731
            avg = lambda a: a.reshape(h, k, w, k, -1).mean((1, 3))  # noqa: E731
            ids, depth = pick(irr)[..., 3], pick(rgb)[..., 3]
            rgb, alb, irr = avg(rgb), avg(alb), avg(irr)
            n = avg(nrm)
            nrm = np.concatenate([n[..., :3] / np.maximum(np.linalg.norm(n[..., :3], axis=-1, keepdims=True), 1e-6), n[..., 3:]], -1)
        else:
            ids, depth = irr[..., 3], rgb[..., 3]
        return {
            "rgb": np.ascontiguousarray(np.maximum(rgb[..., :3], 0)),
            "albedo": np.ascontiguousarray(np.clip(alb[..., :3], 0, 1)),
            "normal": np.ascontiguousarray(nrm[..., :3]),
            "roughness": np.ascontiguousarray(np.clip(alb[..., 3:4], 0, 1)),
            "metallic": np.ascontiguousarray(np.clip(nrm[..., 3:4], 0, 1)),
            "irradiance": np.ascontiguousarray(np.maximum(irr[..., :3], 0)),
            "ids": np.rint(ids).astype(np.int32)[..., None],
            "depth": np.ascontiguousarray(depth[..., None]),
        }

    def release(self) -> None:
        """Free the GL context."""
        self.ctx.release()
