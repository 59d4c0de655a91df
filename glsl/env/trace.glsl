#ifndef VKSHADE_ENV_TRACE_GLSL
#define VKSHADE_ENV_TRACE_GLSL
// The posed character's own visibility per vertex by ray casting (pass `env trace`): the
// fraction of GRID x GRID stratified cosine-weighted rays from the vertex (origin moved
// `offset` along the normal) that escape the posed mesh, through the BVH refitted this frame
// (passes `env bvh leaves`, `env bvh refit`), and which rays escaped (bit k of word k / 32 of
// the vertex's ceil(GRID^2 / 32) words). `env shadow_rays` corrects the caps' split per lobe
// with them (src/kernels/env/mod.rs). Twin: kernels::env::cpu::traced_rays, the same integer
// hash and f32 operations (sin and cos may differ in the last bits, so a ray grazing an edge
// may decide differently).
//
// The rays of a vertex share their origin, so they walk the BVH together, PACKET at a time:
// a node is fetched once and tested against each ray still unblocked, entered when any of
// them meets it, and a leaf's triangles are fetched once and tested against the rays that
// met the leaf. Each ray decides as it would alone (common/bvh.glsl any_hit): a child's box
// lies inside its parent's, and the slab test is monotone in the box's bounds, so a ray
// that misses a node misses every node under it; the walk only skips the nodes that no ray
// enters. Per vertex it fetches the union of the rays' paths once instead of every path.
// PACKET 4: consecutive rays run down an azimuth sector (env/rays.glsl), and a narrow packet
// enters far fewer nodes than the whole hemisphere's. Measured on lavapipe (`bench frame`,
// alternating runs, 4 x 4 rays): the whole hemisphere together 7.4 ms, 8 rays (half the
// azimuths) 6.2, 4 (a quadrant) 5.7, 2 6.4; 4 rays of one radius band across all azimuths 6.3.
#extension GL_EXT_control_flow_attributes : require
#include <common/util.glsl>
#include <env/rays.glsl>
layout(local_size_x = 64) in;

const uint BVH_ROW = 1024u;
// Rays walked together (bits of a uint mask; a divisor of 32): one azimuth sector.
const uint PACKET = 4u;

layout(push_constant) uniform Push {
    uint vertex_count;
    uint grid;
    float offset;
    uint seed;
} pc;

layout(std430, set = 0, binding = 0) readonly buffer Positions { vec4 p[]; } pos;
layout(std430, set = 0, binding = 1) readonly buffer Normals { vec4 n[]; } nrm;
layout(set = 0, binding = 2, rgba32ui) readonly uniform uimage2D nodes;
layout(std430, set = 0, binding = 4) writeonly buffer Traced { float v[]; } traced;
layout(std430, set = 0, binding = 5) writeonly buffer Escaped { uint w[]; } escaped;

#include <common/bvh.glsl>
#include <common/bvh_rounds.glsl>
#include <env/listed.glsl>

// Which of the rays in `live` (bit i: direction d[i]) escape from o, in the rounds of
// common/bvh_rounds.glsl.
uint escaping(vec3 o, vec3 d[PACKET], uint live) {
    vec3 inv[PACKET];
    for (uint i = 0u; i < PACKET; i++) inv[i] = 1.0 / d[i];
    uint ni = 0u;
    uint steps = 0u;
    do {
        uvec3 leaf[ROUND_LEAVES];
        uint found = 0u;
        while (ni != LINK_END && found < ROUND_LEAVES && steps < MAX_STEPS) {
            steps++;
            uvec4 r0 = bvh_texel(2u * ni);
            uvec4 r1 = bvh_texel(2u * ni + 1u);
            vec3 lo = uintBitsToFloat(r0.xyz) - o;
            vec3 hi = uintBitsToFloat(r1.xyz) - o;
            uint meet = 0u;
            for (uint i = 0u; i < PACKET; i++) {
                // tmax infinite.
                meet |= slab_meets(lo, hi, inv[i], uintBitsToFloat(0x7f800000u)) ? (1u << i) : 0u;
            }
            round_node(meet & live, r0, r1, ni, leaf, found);
        }
        uint k = 0u;
        uint j = 0u;
        while (k < found && live != 0u) {
            uvec2 tri = round_triangle(leaf, k, j);
            uint t = tri.x;
            // common/bvh.glsl hit_t, the terms that do not depend on the ray taken once.
            vec3 a = uintBitsToFloat(bvh_texel(t).xyz);
            vec3 e1 = uintBitsToFloat(bvh_texel(t + 1u).xyz);
            vec3 e2 = uintBitsToFloat(bvh_texel(t + 2u).xyz);
            vec3 s = o - a;
            vec3 q = cross(s, e1);
            float tq = dot(e2, q);
            uint hit = 0u;
            for (uint i = 0u; i < PACKET; i++) {
                vec3 p = cross(d[i], e2);
                float det = dot(e1, p);
                float inv_det = 1.0 / det;
                float u = dot(s, p) * inv_det;
                float v = dot(d[i], q) * inv_det;
                float th = tq * inv_det;
                bool h = !(abs(det) < 1e-12) && !(u < 0.0 || u > 1.0) && !(v < 0.0 || u + v > 1.0)
                    && th > 0.0;
                hit |= h ? (1u << i) : 0u;
            }
            live &= ~(hit & tri.y);
        }
    } while (ni != LINK_END && live != 0u && steps < MAX_STEPS);
    return live;
}

void main() {
    uint vi;
    if (!listed_vertex(gl_GlobalInvocationID.x, vi)) return;
    vec3 p = pos.p[vi].xyz;
    vec3 n = nrm.n[vi].xyz;
    vec3 t, bt;
    ray_basis(n, t, bt);
    vec3 o = p + n * pc.offset;
    uint g = pc.grid;
    uint rays = g * g;
    uint words = (rays + 31u) / 32u;
    uint count = 0u;
    uint word = 0u;
    for (uint base = 0u; base < rays; base += PACKET) {
        uint m = min(PACKET, rays - base);
        vec3 d[PACKET];
        for (uint i = 0u; i < PACKET; i++) {
            d[i] = ray_direction(vi, base + min(i, m - 1u), g, pc.seed, t, bt, n);
        }
        uint esc = escaping(o, d, (1u << m) - 1u);
        count += bitCount(esc);
        word |= esc << (base & 31u);
        if (((base + PACKET) & 31u) == 0u || base + PACKET >= rays) {
            escaped.w[vi * words + base / 32u] = word;
            word = 0u;
        }
    }
    traced.v[vi] = float(count) / float(rays);
}
#endif
