#include <common/util.glsl>
// Per-frame BVH of a skinned mesh, step 1, shared by pass `sss bvh leaves` (the skin's vertex
// frames, mm) and pass `env bvh leaves` (the character's posed positions): the topology is
// built once over the rest pose (src/kernels/sss/posed.rs BvhTopology); per leaf, its
// triangles from this pose's vertices, stored as (a, b - a, c - a) in the triangle slots the
// traversal reads, and its box (lo xyz, first; hi xyz, link), both in the one table. Pass
// `sss bvh refit` then fits the inner nodes. The CPU twin is posed::refit.
// The includer declares `const uint BVH_ROW`, its vertex buffer at binding 0 and
// `#define BVH_VERTEX(i)`, the position of vertex i (a vec3).

// Leaves, levels, inner nodes, 0; then per leaf (node, first, link word: count | skip << 8)
// (BvhTopology::gpu; posed::link_words).
layout(std430, set = 0, binding = 1) readonly buffer Topo { uint v[]; } bvh_topo;
// Per triangle slot: the mesh's vertex indices (v0, v1, v2, 0).
layout(std430, set = 0, binding = 2) readonly buffer Slots { uvec4 v[]; } bvh_slots;
// The table of glsl/common/bvh.glsl: nodes from texel 0, triangle slots from TRI_BASE.
layout(set = 0, binding = 3, rgba32ui) writeonly uniform uimage2D nodes;
#include <common/bvh_table.glsl>

ivec2 at(uint k) {
    return table_texel(k, BVH_ROW);
}

void main() {
    uint leaf = gl_GlobalInvocationID.x;
    if (leaf >= bvh_topo.v[0]) return;
    uint node = bvh_topo.v[4u + 3u * leaf];
    uint first = bvh_topo.v[4u + 3u * leaf + 1u];
    uint link = bvh_topo.v[4u + 3u * leaf + 2u];
    uint count = link & 0xffu;
    vec3 lo = vec3(uintBitsToFloat(0x7f800000u));
    vec3 hi = -lo;
    for (uint s = first; s < first + count; s++) {
        uvec4 c = bvh_slots.v[s];
        vec3 a = BVH_VERTEX(c.x), b = BVH_VERTEX(c.y), d = BVH_VERTEX(c.z);
        uint k = TRI_BASE + 3u * s;
        imageStore(nodes, at(k), uvec4(floatBitsToUint(a), 0u));
        imageStore(nodes, at(k + 1u), uvec4(floatBitsToUint(b - a), 0u));
        imageStore(nodes, at(k + 2u), uvec4(floatBitsToUint(d - a), 0u));
        lo = min(lo, min(a, min(b, d)));
        hi = max(hi, max(a, max(b, d)));
    }
    imageStore(nodes, at(2u * node), uvec4(floatBitsToUint(lo), first));
    imageStore(nodes, at(2u * node + 1u), uvec4(floatBitsToUint(hi), link));
}
