#version 450
#include <common/util.glsl>
// Shadowing and transmission per mesh vertex (pass `sss vertex light`), for the irradiance
// pass to interpolate over each triangle (glsl/sss/irradiance.comp): the head has far fewer
// vertices than a 512^2 texture has texels, and a BVH ray is the costly part.
// Per vertex (position, unit normal; src/kernels/sss/cpu.rs vertex_frames):
// - visibility: bit l set when light l is not blocked by the mesh along a ray from
//   p + n * bias toward it (cast whatever the sign of n.l: the texel's own cosine decides
//   the terminator). The same traversal and two-sided Moller-Trumbore test as
//   src/geom/bvh.rs.
// - transmission through thin parts (mode != 0): a ray from just inside along -n finds the
//   back surface at thickness t; its irradiance E_b (its own rays) times R_tot - F(t) per
//   channel (the profile beyond t: a locally flat slab lit from behind): (rgb, t).
// The CPU twin is src/kernels/sss/cpu.rs.
layout(local_size_x = 64) in;

layout(push_constant) uniform Push {
    uint vertices;
    uint lights;
    float bias;    // shadow-ray origin offset along the normal (mm)
    uint mode;     // transmission: 0 off, 1 dipole, 2 Burley
} pc;

layout(std430, set = 0, binding = 0) readonly buffer Verts { vec4 v[]; } verts;   // pos, normal
// The BVH as one table (row BVH_ROW; glsl/common/bvh.glsl): nodes 2 texels each, then
// triangles 3 each from texel TRI_BASE.
const uint BVH_ROW = 1024u;
layout(set = 0, binding = 1, rgba32ui) readonly uniform uimage2D nodes;

#include <sss/lights.glsl>
// Outputs as images (vertex v at (v % VERTEX_ROW, v / VERTEX_ROW)): the irradiance pass
// gathers them with one texel fetch each.
const uint VERTEX_ROW = 1024u;
layout(set = 0, binding = 4, r32ui) writeonly uniform uimage2D vis;
layout(set = 0, binding = 5, rgba32f) writeonly uniform image2D vtrans; // rgb, t
// The skin regions' profiles (src/kernels/sss/regions.rs; pack::region_tails), four vec4 a
// region: per channel the tail, dipole (alpha'/2, sigma_tr, z_r, z_v) or Burley (A, d, 0,
// 0); then (the thickest part that transmits (mm), 0, 0, 0). A vertex takes its region's
// (`vregion`: the lowest region of its triangles, Regions::of_vertices).
const uint MAX_REGIONS = 8u;
layout(std140, set = 0, binding = 6) uniform Tails { vec4 v[4u * MAX_REGIONS]; } tails;
layout(std430, set = 0, binding = 7) readonly buffer VRegion { uint v[]; } vregion;

#include <common/bvh.glsl>

// Visibility bits of the lights from p (normal n), rays from p + n * bias.
// A vertex's shadow rays toward RAY_PACKET lights at a time walk the BVH together
// (glsl/sss/packet.glsl: each decides as it would alone).
const uint RAY_PACKET = 2u;
#include <sss/packet.glsl>
#include <sss/transmission.glsl>

uint visibility(vec3 p, vec3 n) {
    vec3 o = p + n * pc.bias;
    uint bits = 0u;
    for (uint base = 0u; base < pc.lights; base += RAY_PACKET) {
        vec3 os[RAY_PACKET], ds[RAY_PACKET];
        float tmax[RAY_PACKET];
        uint live = 0u;
        for (uint k = 0u; k < RAY_PACKET; k++) {
            // Past the last light: the last again, not walked.
            float strength;
            light_at(min(base + k, pc.lights - 1u), p, n, ds[k], tmax[k], strength);
            os[k] = o;
            live |= (base + k < pc.lights ? 1u : 0u) << k;
        }
        bits |= (live & ~blocked_rays(os, ds, tmax, live)) << base;
    }
    return bits;
}

// Irradiance at p (normal n) from every light, shadow rays from p + n * bias.
float irradiance_at(vec3 p, vec3 n) {
    vec3 o = p + n * pc.bias;
    float e = 0.0;
    for (uint l = 0u; l < pc.lights; l++) {
        vec3 dir;
        float tmax, strength;
        float c = light_at(l, p, n, dir, tmax, strength);
        if (c <= 0.0 || strength == 0.0) continue;
        if (any_hit(o, dir, tmax)) continue;
        e += strength * c;
    }
    return e;
}

float tail(uint r, uint c, float t) {
    vec4 p = tails.v[4u * r + c];
    if (pc.mode == 1u) {
        float dr = sqrt(t * t + p.z * p.z);
        float dv = sqrt(t * t + p.w * p.w);
        return p.x * (p.z * exp(-p.y * dr) / dr + p.w * exp(-p.y * dv) / dv);
    }
    return p.x * (0.25 * exp(-t / p.y) + 0.75 * exp(-t / (3.0 * p.y)));
}

void main() {
    uint v = gl_GlobalInvocationID.x;
    if (v >= pc.vertices) return;
    vec3 p = verts.v[2u * v].xyz;
    vec3 n = verts.v[2u * v + 1u].xyz;
    ivec2 at = table_texel(v, VERTEX_ROW);
    imageStore(vis, at, uvec4(visibility(p, n)));
    vec4 tr = vec4(0.0);
    if (TRANSMISSION && pc.mode != 0u) {
        uint r = min(vregion.v[v], MAX_REGIONS - 1u);
        vec3 o = p - n * pc.bias;
        vec2 h = closest_hit(o, -n, tails.v[4u * r + 3u].x);
        if (h.x >= 0.0) {
            uint k = floatBitsToUint(h.y);
            vec3 nb = normalize(cross(tri_row(3u * k + 1u), tri_row(3u * k + 2u)));
            if (dot(nb, n) > 0.0) nb = -nb;
            vec3 xb = o - n * h.x;
            float eb = irradiance_at(xb, nb);
            float thick = h.x + pc.bias;
            tr = vec4(eb * tail(r, 0u, thick), eb * tail(r, 1u, thick), eb * tail(r, 2u, thick),
                thick);
        }
    }
    imageStore(vtrans, at, tr);
}
