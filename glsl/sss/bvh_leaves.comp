#version 450
// Per-frame BVH of a skinned mesh, step 1 (pass `sss bvh leaves`): the topology is built once
// over the rest pose (src/kernels/sss/posed.rs BvhTopology); per leaf, its triangles from the
// vertex frames of this pose (`verts`, mm), stored as (a, b - a, c - a) in the triangle slots
// the traversal reads (`tris`), and its box (`nodes`: lo xyz, first; hi xyz, link). Pass
// `sss bvh refit` then fits the inner nodes. The CPU twin is posed::refit.
layout(local_size_x = 64) in;

const uint BVH_ROW = 1024u;

layout(std430, set = 0, binding = 0) readonly buffer Verts { vec4 v[]; } verts;
// Leaves, levels, inner nodes, 0; then per leaf (node, first, link word: count | skip << 8)
// (BvhTopology::gpu; posed::link_words).
layout(std430, set = 0, binding = 1) readonly buffer Topo { uint v[]; } bvh_topo;
// Per triangle slot: the mesh's vertex indices (v0, v1, v2, 0).
layout(std430, set = 0, binding = 2) readonly buffer Slots { uvec4 v[]; } bvh_slots;
layout(set = 0, binding = 3, rgba32ui) writeonly uniform uimage2D nodes;
layout(set = 0, binding = 4, rgba32ui) writeonly uniform uimage2D tris;

ivec2 at(uint k) {
    return ivec2(k % BVH_ROW, k / BVH_ROW);
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
        vec3 a = verts.v[2u * c.x].xyz, b = verts.v[2u * c.y].xyz, d = verts.v[2u * c.z].xyz;
        imageStore(tris, at(3u * s), uvec4(floatBitsToUint(a), 0u));
        imageStore(tris, at(3u * s + 1u), uvec4(floatBitsToUint(b - a), 0u));
        imageStore(tris, at(3u * s + 2u), uvec4(floatBitsToUint(d - a), 0u));
        lo = min(lo, min(a, min(b, d)));
        hi = max(hi, max(a, max(b, d)));
    }
    imageStore(nodes, at(2u * node), uvec4(floatBitsToUint(lo), first));
    imageStore(nodes, at(2u * node + 1u), uvec4(floatBitsToUint(hi), link));
}
