"""GLSL sources of the procedural renderer: G-buffer + PBR shading pass (all channels at once) and shadow passes."""
from __future__ import annotations

MAX_LIGHTS = 10
MAX_OCCLUDERS = 40

#: faces of a cube map in OpenGL order (+X, -X, +Y, -Y, +Z, -Z): (forward, right, up) chosen so that the image
#: rendered with right/up as NDC x/y is exactly what glTexImage2D expects for that face (GL spec table 8.19)
CUBE_FACES = (
    ((1, 0, 0), (0, 0, -1), (0, -1, 0)),
    ((-1, 0, 0), (0, 0, 1), (0, -1, 0)),
    ((0, 1, 0), (1, 0, 0), (0, 0, 1)),
    ((0, -1, 0), (1, 0, 0), (0, 0, -1)),
    ((0, 0, 1), (1, 0, 0), (0, -1, 0)),
    ((0, 0, -1), (-1, 0, 0), (0, -1, 0)),
)

_FACES_GLSL = "\n".join(
    f"    if (face == {i}) {{ F = vec3{f}; R = vec3{r}; U = vec3{u}; }}" for i, (f, r, u) in enumerate(CUBE_FACES)
)

VERTEX = """
#version 330
uniform mat4 u_viewproj;
in vec3 in_pos; in vec3 in_nrm; in float in_mat; in float in_id;
out vec3 v_pos; out vec3 v_nrm; flat out int v_mat; flat out int v_id;
void main() {
    v_pos = in_pos; v_nrm = in_nrm; v_mat = int(in_mat + 0.5); v_id = int(in_id + 0.5);
    gl_Position = u_viewproj * vec4(in_pos, 1.0);
}
"""

#: distance-to-light pass (point-light cube faces and the sun's orthographic map); non-casters are clipped away
SHADOW_VERTEX = """
#version 330
uniform mat4 u_viewproj;
in vec3 in_pos; in float in_shadow;
out vec3 v_pos;
void main() {
    v_pos = in_pos;
    gl_Position = in_shadow > 0.5 ? u_viewproj * vec4(in_pos, 1.0) : vec4(2.0, 2.0, 2.0, 1.0);
}
"""
SHADOW_FRAGMENT = """
#version 330
uniform vec3 u_origin; uniform vec3 u_axis; uniform int u_ortho;
in vec3 v_pos; out float dist;
void main() { dist = u_ortho == 1 ? dot(v_pos - u_origin, u_axis) : length(v_pos - u_origin); }
"""

FRAGMENT = """
#version 330
#define MAXL %(MAXL)d
#define MAXO %(MAXO)d
#define PI 3.14159265
uniform vec3 u_campos; uniform mat3 u_viewrot; uniform mat4 u_view;
uniform sampler2D u_materials;      // (4, M) RGBA32F: albedo+pattern | rough, metal, scale, contrast | emission+sky | -
uniform sampler2D u_shadow_atlas;   // 6 faces x MAXL lights, R32F distance to the light
uniform int u_shadow_size;
uniform int u_nl;
uniform vec3 u_lpos[MAXL]; uniform vec3 u_lcol[MAXL]; uniform float u_lrad2[MAXL]; uniform vec4 u_ldir[MAXL];
uniform int u_has_sun; uniform vec3 u_sun_dir; uniform vec3 u_sun_col; uniform mat4 u_sun_vp; uniform sampler2D u_sun_map;
uniform vec3 u_sun_origin;
uniform vec3 u_sh[9];               // irradiance SH (already convolved, divided by pi)
uniform samplerCube u_env; uniform int u_has_env; uniform vec3 u_probe; uniform vec3 u_box_lo; uniform vec3 u_box_hi;
uniform float u_env_mips; uniform float u_emission_scale;
uniform sampler2D u_planar; uniform int u_has_planar; uniform float u_planar_mips;  // mirror image of the room in the floor
uniform int u_clip_floor;           // 1 while rendering that mirror image: drop what lies below the floor plane
uniform int u_nocc; uniform vec3 u_occ_lo[MAXO]; uniform vec3 u_occ_hi[MAXO]; uniform int u_occ_id[MAXO];  // furniture boxes

in vec3 v_pos; in vec3 v_nrm; flat in int v_mat; flat in int v_id;
layout(location = 0) out vec4 o_rgb;      // rgb, view depth
layout(location = 1) out vec4 o_albedo;   // albedo, roughness
layout(location = 2) out vec4 o_normal;   // camera-space normal, metallic
layout(location = 3) out vec4 o_irr;      // irradiance, object id

float hash(vec2 p) { return fract(sin(dot(p, vec2(127.1, 311.7))) * 43758.5453); }
float vnoise(vec2 p) {
    vec2 i = floor(p), f = fract(p); f = f * f * (3.0 - 2.0 * f);
    return mix(mix(hash(i), hash(i + vec2(1, 0)), f.x), mix(hash(i + vec2(0, 1)), hash(i + vec2(1, 1)), f.x), f.y);
}
float fbm(vec2 p) { return 0.5 * vnoise(p) + 0.3 * vnoise(p * 2.03 + 7.1) + 0.2 * vnoise(p * 4.01 + 3.3); }

// a line of half-width `hw` at distance `g` from its centre, box-filtered over a pixel of size `px` (coverage 0..1)
float line_cov(float g, float hw, float px) {
    px = max(px, 1e-6);
    return clamp(min(g + 0.5 * px, hw) - max(g - 0.5 * px, -hw), 0.0, px) / px;
}

// integral of the square wave step(0.5, fract(t)), for box-filtered stripes
float sq_int(float t) { return floor(t) * 0.5 + max(fract(t) - 0.5, 0.0); }

// multiplicative albedo modulation of a procedural pattern (mean close to 1), filtered against aliasing:
// features smaller than a pixel fade to their mean (px = pixel footprint in metres)
float pattern_raw(int kind, vec2 uv, float s, float c, float px) {
    if (kind == 1) {            // planks along x, staggered joints, dark grooves
        float row = floor(uv.y / s);
        float len = 1.2;
        float sh = hash(vec2(row, 3.0));
        float seg = floor(uv.x / len + sh);
        float g = min(fract(uv.y / s), 1.0 - fract(uv.y / s)) * s;
        float e = min(fract(uv.x / len + sh), 1.0 - fract(uv.x / len + sh)) * len;
        float m = 1.0 + c * (2.0 * hash(vec2(row, seg)) - 1.0) + 0.5 * c * (fbm(vec2(uv.x * 2.0, uv.y * 40.0)) - 0.5);
        float groove = max(line_cov(g, 0.003, px), line_cov(e, 0.003, px));
        return m * (1.0 - 0.45 * groove);
    }
    if (kind == 2) {            // tiles with grout lines
        vec2 cell = floor(uv / s); vec2 f = fract(uv / s);
        float g = min(min(f.x, 1.0 - f.x), min(f.y, 1.0 - f.y)) * s;
        return mix(1.0 + c * (2.0 * hash(cell) - 1.0), 0.7, line_cov(g, 0.003, px));
    }
    if (kind == 3) {            // stripes, box-filtered over the pixel
        float w = max(px / s, 1e-4);
        float x = uv.x / s;
        float dark = (sq_int(x + 0.5 * w) - sq_int(x - 0.5 * w)) / w;
        return mix(1.0 + c, 1.0 - c, dark);
    }
    if (kind == 4) return 1.0 + 2.0 * c * (fbm(uv / s) - 0.5);          // noise
    if (kind == 5) return 1.0 + 2.0 * c * (fbm(vec2(uv.x / (s * 12.0), uv.y / s)) - 0.5) + 0.6 * c * sin(uv.y / s * 6.0 + 3.0 * fbm(uv / (s * 5.0)));  // grain
    if (kind == 6) {            // marble veins
        float v = abs(sin((uv.x + uv.y) / s * 2.0 + 6.0 * fbm(uv / s)));
        return 1.0 + c * 0.4 - c * 1.5 * pow(clamp(1.0 - v, 0.0, 1.0), 6.0);
    }
    return 1.0;
}

float pattern(int kind, vec2 uv, float s, float c) {
    float px = max(length(dFdx(uv)), length(dFdy(uv)));
    float m = pattern_raw(kind, uv, s, c, px);
    // noise-like detail finer than ~2 pixels fades to its mean (the grooves, grout and stripes filter themselves)
    float fade = (kind >= 4) ? clamp(2.0 - px / (0.25 * s), 0.0, 1.0) : 1.0;
    return mix(1.0, m, fade);
}

vec2 atlas_uv(int light, vec3 D) {  // direction from the light -> uv in the shadow atlas
    vec3 a = abs(D); int face;
    if (a.x >= a.y && a.x >= a.z) face = D.x > 0.0 ? 0 : 1;
    else if (a.y >= a.z) face = D.y > 0.0 ? 2 : 3;
    else face = D.z > 0.0 ? 4 : 5;
    vec3 F, R, U;
%(FACES)s
    vec2 st = vec2(dot(D, R), dot(D, U)) / dot(D, F) * 0.5 + 0.5;
    float m = 2.5 / float(u_shadow_size);
    st = clamp(st, vec2(m), vec2(1.0 - m));
    return (vec2(float(face), float(light)) + st) / vec2(6.0, float(MAXL));
}

// bilinearly weighted depth comparisons of the 2x2 texels around texel position tc (texel units): smooth edges
float pcf2(sampler2D map, vec2 tc, float ref) {
    vec2 b = floor(tc - 0.5), f = tc - 0.5 - b;
    ivec2 hi = textureSize(map, 0) - 1;
    float s00 = ref <= texelFetch(map, clamp(ivec2(b), ivec2(0), hi), 0).r ? 1.0 : 0.0;
    float s10 = ref <= texelFetch(map, clamp(ivec2(b) + ivec2(1, 0), ivec2(0), hi), 0).r ? 1.0 : 0.0;
    float s01 = ref <= texelFetch(map, clamp(ivec2(b) + ivec2(0, 1), ivec2(0), hi), 0).r ? 1.0 : 0.0;
    float s11 = ref <= texelFetch(map, clamp(ivec2(b) + ivec2(1, 1), ivec2(0), hi), 0).r ? 1.0 : 0.0;
    return mix(mix(s00, s10, f.x), mix(s01, s11, f.x), f.y);
}

// a tent filter two texels wide: four bilinear PCF lookups
float pcf(sampler2D map, vec2 uv, float ref) {
    vec2 tc = uv * vec2(textureSize(map, 0));
    return 0.25 * (pcf2(map, tc + vec2(-0.5, -0.5), ref) + pcf2(map, tc + vec2(0.5, -0.5), ref)
                 + pcf2(map, tc + vec2(-0.5, 0.5), ref) + pcf2(map, tc + vec2(0.5, 0.5), ref));
}

float point_shadow(int i, vec3 P, vec3 N, vec3 L) {
    float texel = 2.0 * length(P - u_lpos[i]) / float(u_shadow_size);  // shadow-map texel size there, metres
    vec3 Q = P + N * (0.005 + 2.0 * texel) + L * 0.01;  // normal offset against acne at grazing angles
    vec3 D = Q - u_lpos[i];
    float d = length(D);
    return pcf(u_shadow_atlas, atlas_uv(i, D), d - 0.02 * d);
}

float sun_shadow(vec3 P, vec3 N) {
    vec3 Q = P + N * 0.02;
    vec4 c = u_sun_vp * vec4(Q, 1.0);
    vec2 uv = c.xy * 0.5 + 0.5;
    if (any(lessThan(uv, vec2(0.0))) || any(greaterThan(uv, vec2(1.0)))) return 1.0;
    float d = dot(Q - u_sun_origin, -u_sun_dir);
    return pcf(u_sun_map, uv, d - 0.03);
}

// ambient occlusion of the indirect light by nearby furniture, each taken as its bounding box: the closer the box and
// the more it faces the surface, the less ambient light arrives (world space, so it does not flicker between frames)
float furniture_ao(vec3 P, vec3 N, int id) {
    float occ = 0.0;
    for (int i = 0; i < MAXO; i++) {
        if (i >= u_nocc) break;
        if (u_occ_id[i] == id) continue;
        vec3 lo = u_occ_lo[i], hi = u_occ_hi[i];
        float R = clamp(0.6 * length(hi - lo), 0.15, 0.6);  // reach of the occlusion
        vec3 q = clamp(P, lo, hi);
        vec3 dv = q - P;
        float d = length(dv);
        if (d >= R) continue;
        float facing = d < 1e-3 ? 1.0 : clamp(dot(N, dv / d) * 0.75 + 0.25, 0.0, 1.0);
        float k = 1.0 - d / R;
        occ += 0.55 * k * k * facing;
    }
    return clamp(1.0 - occ, 0.35, 1.0);
}

vec3 sh_irradiance(vec3 n) {
    return max(u_sh[0] * 0.282095 + u_sh[1] * 0.488603 * n.y + u_sh[2] * 0.488603 * n.z + u_sh[3] * 0.488603 * n.x
         + u_sh[4] * 1.092548 * n.x * n.y + u_sh[5] * 1.092548 * n.y * n.z + u_sh[6] * 0.315392 * (3.0 * n.z * n.z - 1.0)
         + u_sh[7] * 1.092548 * n.x * n.z + u_sh[8] * 0.546274 * (n.x * n.x - n.y * n.y), vec3(0.0));
}

// GGX microfacet specular BRDF (Cook-Torrance with Smith-Schlick G and Schlick F)
vec3 ggx(vec3 N, vec3 V, vec3 L, float rough, vec3 F0) {
    vec3 H = normalize(V + L);
    float a = max(rough * rough, 0.002), a2 = a * a;
    float nh = max(dot(N, H), 0.0), nv = max(dot(N, V), 1e-3), nl = max(dot(N, L), 1e-3);
    float dd = nh * nh * (a2 - 1.0) + 1.0;
    float D = a2 / (PI * dd * dd);
    float k = (rough + 1.0) * (rough + 1.0) / 8.0;
    float G = nv / (nv * (1.0 - k) + k) * nl / (nl * (1.0 - k) + k);
    vec3 F = F0 + (1.0 - F0) * pow(clamp(1.0 - dot(H, V), 0.0, 1.0), 5.0);
    return D * G * F / (4.0 * nv * nl);
}

vec3 env_brdf(vec3 F0, float rough, float nv) {   // Karis' analytic fit of the split-sum environment BRDF
    vec4 c0 = vec4(-1.0, -0.0275, -0.572, 0.022), c1 = vec4(1.0, 0.0425, 1.04, -0.04);
    vec4 r = rough * c0 + c1;
    float a004 = min(r.x * r.x, exp2(-9.28 * nv)) * r.x + r.y;
    vec2 ab = vec2(-1.04, 1.04) * a004 + r.zw;
    return F0 * ab.x + ab.y;
}

void main() {
    if (u_clip_floor == 1 && v_pos.y < 0.002) discard;
    vec4 m0 = texelFetch(u_materials, ivec2(0, v_mat), 0);
    vec4 m1 = texelFetch(u_materials, ivec2(1, v_mat), 0);
    vec4 m2 = texelFetch(u_materials, ivec2(2, v_mat), 0);
    vec3 N = normalize(v_nrm);
    vec3 P = v_pos;
    vec3 V = normalize(u_campos - P);
    float depth = -(u_view * vec4(P, 1.0)).z;
    vec3 ncam = normalize(u_viewrot * N);
    if (m2.a > 0.5) {  // sky through a window: only emitted light, no albedo/irradiance, id 0 (background)
        o_rgb = vec4(m2.rgb * u_emission_scale, depth); o_albedo = vec4(0.0, 0.0, 0.0, 1.0); o_normal = vec4(ncam, 0.0); o_irr = vec4(0.0);
        return;
    }
    vec3 an = abs(N);
    vec2 uv = an.y > max(an.x, an.z) ? P.xz : (an.x > an.z ? P.zy : P.xy);
    vec3 albedo = clamp(m0.rgb * pattern(int(m0.a + 0.5), uv, m1.b, m1.a), 0.0, 1.0);
    float rough = clamp(m1.r, 0.0, 1.0), metal = clamp(m1.g, 0.0, 1.0);
    // dielectric specular fades out towards roughness 1 (roughness 1 + metallic 0 = purely Lambertian)
    float spec_w = 1.0 - smoothstep(0.7, 1.0, rough);
    vec3 F0 = mix(vec3(0.04), albedo, metal);
    float sw = mix(spec_w, 1.0, metal);  // weight of all specular terms
    vec3 irr = vec3(0.0), spec = vec3(0.0);
    for (int i = 0; i < MAXL; i++) {
        if (i >= u_nl) break;
        vec3 Lv = u_lpos[i] - P; float d2 = dot(Lv, Lv); vec3 L = Lv * inversesqrt(d2);
        float nl = dot(N, L);
        if (nl <= 0.0) continue;
        float lobe = u_ldir[i].w > 0.5 ? max(dot(-L, u_ldir[i].xyz), 0.0) : 1.0;
        if (lobe <= 0.0) continue;
        vec3 E = u_lcol[i] * (nl * lobe / (d2 + u_lrad2[i])) * point_shadow(i, P, N, L);
        irr += E;
        spec += ggx(N, V, L, rough, F0) * (PI * sw) * E;
    }
    if (u_has_sun == 1) {
        float nl = dot(N, u_sun_dir);
        if (nl > 0.0) {
            vec3 E = u_sun_col * nl * sun_shadow(P, N);
            irr += E;
            spec += ggx(N, V, u_sun_dir, rough, F0) * (PI * sw) * E;
        }
    }
    irr += sh_irradiance(N) * furniture_ao(P, N, v_id);
    vec3 refl = vec3(0.0);
    if (u_has_planar == 1 && N.y > 0.99 && P.y < 0.02) {  // the floor (and rugs on it): planar reflection
        vec3 env = textureLod(u_planar, gl_FragCoord.xy / vec2(textureSize(u_planar, 0)), rough * u_planar_mips).rgb;
        refl = env * env_brdf(F0, rough, max(dot(N, V), 1e-3)) * sw;
    } else if (u_has_env == 1) {  // box-projected (parallax-corrected) reflection probe, blurred by roughness
        vec3 R = reflect(-V, N);
        vec3 t1 = (u_box_hi - P) / R, t2 = (u_box_lo - P) / R;
        vec3 tf = max(t1, t2);
        float t = min(min(tf.x, tf.y), tf.z);
        vec3 dir = P + R * max(t, 0.0) - u_probe;
        vec3 env = textureLod(u_env, dir, rough * u_env_mips).rgb;
        refl = env * env_brdf(F0, rough, max(dot(N, V), 1e-3)) * sw;
    }
    vec3 rgb = albedo * (1.0 - metal) * irr + spec + refl + m2.rgb * u_emission_scale;
    o_rgb = vec4(rgb, depth);
    o_albedo = vec4(albedo, rough);
    o_normal = vec4(ncam, metal);
    o_irr = vec4(irr, float(v_id));
}
""" % {"MAXL": MAX_LIGHTS, "MAXO": MAX_OCCLUDERS, "FACES": _FACES_GLSL}
