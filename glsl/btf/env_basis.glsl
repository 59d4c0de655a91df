// `btf env basis`, included by btf/env_basis.comp (every pixel) and btf/env_basis_pixels.comp
// (BTF_PIXELS: over the pixel list of pass `btf pixels`, 64 pixels a workgroup, dispatched
// indirectly, as `btf shade` over it): cloth under the SG environment through the BTF's light basis
// (src/kernels/btf/basis.rs has the method; BasisData::shade is the CPU twin). Per covered
// pixel of a part in the mask: each lobe's axis into the tangent frame, its RANK basis
// weights Q_jk from the lobe's octahedral table (2 filtered fetches), summed as
// L_k = sum_j (V_j a_j / pi) Q_jk; then sum_k L_k B_k(uv, view) over the 3 view taps of the
// direction map (GROUPS filtered fetches each), ADDED to `result` (the pass runs after
// `btf shade`). V_j: 1, per pixel ([pixel * J + j]) or per vertex ([vertex * J + j],
// interpolated by the barycentrics of the G-buffer position on the pixel's triangle). Mode 3:
// L_k itself per vertex (pass `btf env vertices`, glsl/btf/env_vertices.comp), interpolated
// by those barycentrics, the front or back face's as the pixel's normal faces the
// vertices' (the rasteriser negates a back face's), plus those of the lobes in `plobes`
// (kernels::btf::basis::BasisData::pixel_lobes) looked up here with the visibility
// interpolated as in mode 2.

layout(push_constant) uniform Push {
    vec4 camera; // xyz: camera position; w = 0: xyz is the direction towards an
                 // orthographic camera instead
    uvec4 dims;  // width, height, lobes J, visibility mode (0 none, 1 per pixel, 2 per vertex,
                 // 3 light per vertex)
    uvec4 info;  // x: part mask (bit p: shade part p), y: mode 3's entries of `plobes`
} pc;

const uint GROUPS = 6u; // basis.rs GROUPS
// Whether any lobe is looked up per pixel: false only in mode 3 with no entry in `plobes`
// (BtfKernel::add_env_basis sets it; the character frame's default). A loop whose count is a
// push word runs its first iteration's body on lavapipe even when it counts 0 (under a lane
// mask: two filtered table fetches and the visibility loads every pixel), so without such
// lobes it is compiled out (`bench frame`, fastest of 6 alternated runs: 2.26 -> 2.08 ms).
layout(constant_id = 0) const bool PER_PIXEL_LOBES = true;

layout(set = 0, binding = 0) uniform texture2DArray coeffs[GROUPS];
layout(set = 0, binding = 1) uniform sampler coeff_sampler;  // linear, repeat
layout(set = 0, binding = 2) uniform texture2DArray table;
layout(set = 0, binding = 3) uniform sampler table_sampler;  // linear, clamp to edge
layout(set = 0, binding = 4) uniform utexture2D dir_map;
layout(set = 0, binding = 5) uniform texture2DArray gbuffer;
layout(std430, set = 0, binding = 6) buffer Result { vec4 v[]; } result;
// Two vec4 per lobe: (axis xyz world, sharpness), (amplitude rgb, 0).
layout(std430, set = 0, binding = 7) readonly buffer Lobes { vec4 v[]; } lobes;
layout(std430, set = 0, binding = 8) readonly buffer PixelVisibility { float v[]; } pixel_vis;
layout(std430, set = 0, binding = 9) readonly buffer Keys { uvec2 k[]; } keys;
layout(std430, set = 0, binding = 10) readonly buffer Positions { vec4 p[]; } pos;
layout(std430, set = 0, binding = 11) readonly buffer Triangles { uvec4 t[]; } tris;
layout(std430, set = 0, binding = 12) readonly buffer VertexVisibility { float v[]; } vertex_vis;
#include <common/btf_pixels.glsl>
// Mode 3: pass `btf env vertices`' light factors (glsl/btf/basis_light.glsl has the layout).
layout(set = 0, binding = 14, rgba32f) readonly uniform image2D vertex_light;
// Mode 3: the lobes looked up at each pixel all the same
// (kernels::btf::basis::BasisData::pixel_lobes).
layout(std430, set = 0, binding = 15) readonly buffer PixelLobes { uint j[]; } plobes;

#include "basis_light.glsl"

void lookup(vec3 d, out uvec3 index, out vec3 weight) {
    ivec2 n = textureSize(dir_map, 0);
    vec2 p = d.xy / (1.0 + d.z);
    ivec2 t = clamp(ivec2(floor((p + 1.0) * 0.5 * vec2(n))), ivec2(0), n - 1);
    uvec4 m = texelFetch(dir_map, t, 0);
    index = uvec3(m.x & 0xFFu, (m.x >> 8u) & 0xFFu, (m.x >> 16u) & 0xFFu);
    weight = uintBitsToFloat(m.yzw);
}

// basis.rs barycentrics.
vec3 barycentrics(vec3 p, vec3 a, vec3 b, vec3 c) {
    vec3 e1 = b - a, e2 = c - a, d = p - a;
    float d00 = dot(e1, e1), d01 = dot(e1, e2), d11 = dot(e2, e2);
    float d20 = dot(d, e1), d21 = dot(d, e2);
    float den = d00 * d11 - d01 * d01;
    if (abs(den) <= 1e-30) return vec3(1.0, 0.0, 0.0);
    float v = clamp((d11 * d20 - d01 * d21) / den, 0.0, 1.0);
    float w = clamp((d00 * d21 - d01 * d20) / den, 0.0, 1.0 - v);
    return vec3(1.0 - v - w, v, w);
}

void main() {
    uvec2 px;
    if (!shaded_pixel(pc.dims.xy, px)) return;
    uint k = px.y * pc.dims.x + px.x;
    vec4 g0 = texelFetch(gbuffer, ivec3(px, 0), 0);
    if (abs(g0.w) < 0.5) return;
    uint part = uint(abs(g0.w)) - 1u;
    if (part >= 32u || (pc.info.x & (1u << part)) == 0u) return;
    vec4 g1 = texelFetch(gbuffer, ivec3(px, 1), 0);
    vec4 g2 = texelFetch(gbuffer, ivec3(px, 2), 0);
    vec3 n = normalize(g1.xyz);
    vec3 t = normalize(g2.xyz - n * dot(n, g2.xyz));
    vec3 bt = (g0.w < 0.0 ? -1.0 : 1.0) * cross(n, t);
    vec3 view = pc.camera.w == 0.0 ? pc.camera.xyz : normalize(pc.camera.xyz - g0.xyz);
    vec3 vt = vec3(dot(view, t), dot(view, bt), dot(view, n));
    if (vt.z <= 0.0) return;

    uint J = pc.dims.z;
    uint mode = pc.dims.w;
    uvec4 tri = uvec4(0u);
    vec3 bary = vec3(0.0);
    if (mode >= 2u) {
        tri = tris.t[keys.k[k].x];
        bary = barycentrics(g0.xyz, pos.p[tri.x].xyz, pos.p[tri.y].xyz, pos.p[tri.z].xyz);
    }
    vec3 l[RANK];
    for (uint q = 0u; q < RANK; q++) l[q] = vec3(0.0);
    if (mode == 3u) {
        vec3 nv = bary.x * imageLoad(vertex_light, light_texel(tri.x, LIGHT_NORMAL)).xyz
            + bary.y * imageLoad(vertex_light, light_texel(tri.y, LIGHT_NORMAL)).xyz
            + bary.z * imageLoad(vertex_light, light_texel(tri.z, LIGHT_NORMAL)).xyz;
        uint side = dot(g1.xyz, nv) < 0.0 ? LIGHT_BACK : 0u;
        float f[RANK * 3u];
        for (uint i = 0u; i < RANK * 3u / 4u; i++) {
            vec4 a = bary.x * imageLoad(vertex_light, light_texel(tri.x, side + i))
                + bary.y * imageLoad(vertex_light, light_texel(tri.y, side + i))
                + bary.z * imageLoad(vertex_light, light_texel(tri.z, side + i));
            f[4u * i] = a.x;
            f[4u * i + 1u] = a.y;
            f[4u * i + 2u] = a.z;
            f[4u * i + 3u] = a.w;
        }
        for (uint q = 0u; q < RANK; q++) l[q] = vec3(f[3u * q], f[3u * q + 1u], f[3u * q + 2u]);
    }
    uint count = mode == 3u ? pc.info.y : J;
    if (PER_PIXEL_LOBES) for (uint m = 0u; m < count; m++) {
        uint j = mode == 3u ? plobes.j[m] : m;
        vec4 p = lobes.v[2u * j];
        vec3 amp = lobes.v[2u * j + 1u].rgb;
        float v = 1.0;
        if (mode == 1u) {
            v = pixel_vis.v[k * J + j];
        } else if (mode >= 2u) {
            v = bary.x * vertex_vis.v[tri.x * J + j] + bary.y * vertex_vis.v[tri.y * J + j]
                + bary.z * vertex_vis.v[tri.z * J + j];
        }
        add_lobe(l, amp * (v * (1.0 / PI)), vec3(dot(p.xyz, t), dot(p.xyz, bt), dot(p.xyz, n)), j);
    }
    uvec3 iv;
    vec3 wv;
    lookup(vt, iv, wv);
    vec2 uv = vec2(g1.w, g2.w);
    // The coefficients B_s (s = 3 k + channel) of the 3 view taps, weighted.
    vec4 b[GROUPS];
    for (uint g = 0u; g < GROUPS; g++) b[g] = vec4(0.0);
    for (int a = 0; a < 3; a++) {
        if (wv[a] == 0.0) continue;
        for (uint g = 0u; g < GROUPS; g++) {
            b[g] += wv[a] * textureLod(sampler2DArray(coeffs[g], coeff_sampler),
                                       vec3(uv, float(iv[a])), 0.0);
        }
    }
    // sum_k L_k B_k per channel: scalar s = 4 g + c is channel s % 3 of coefficient s / 3.
    float f[RANK * 3u];
    for (uint s = 0u; s < RANK * 3u; s++) f[s] = b[s / 4u][s % 4u];
    vec3 sum = vec3(0.0);
    for (uint q = 0u; q < RANK; q++) sum += l[q] * vec3(f[3u * q], f[3u * q + 1u], f[3u * q + 2u]);
    result.v[k] += vec4(sum, 0.0);
}
