#version 450
#include <common/util.glsl>
// Per-frame BVH of a skinned mesh, step 2 (pass `sss bvh refit`): the inner nodes' boxes, the
// union of their children's, one level of the tree after the other from the deepest (the
// leaves' boxes come from pass `sss bvh leaves`). One workgroup: a level's nodes are spread
// over its invocations, and a barrier separates the levels (a head's tree has a few thousand
// inner nodes over a few dozen levels). The CPU twin is src/kernels/sss/posed.rs refit.
layout(local_size_x = 64) in;

const uint BVH_ROW = 1024u;

// Leaves, levels, inner nodes, 0; per leaf (node, first, link word); per inner node (node,
// left child, link word: skip << 8), deepest level first; the level starts
// (BvhTopology::gpu; posed::link_words).
layout(std430, set = 0, binding = 0) readonly buffer Topo { uint v[]; } bvh_topo;
// Read (children) and written (parents) by the same workgroup: coherent, with a memory
// barrier and a control barrier between levels.
layout(set = 0, binding = 1, rgba32ui) coherent uniform uimage2D nodes;

ivec2 at(uint k) {
    return table_texel(k, BVH_ROW);
}

void main() {
    uint leaves = bvh_topo.v[0];
    uint levels = bvh_topo.v[1];
    uint inner = bvh_topo.v[2];
    uint inner_at = 4u + 3u * leaves;
    uint starts_at = inner_at + 3u * inner;
    for (uint l = 0u; l < levels; l++) {
        uint begin = bvh_topo.v[starts_at + l];
        uint end = bvh_topo.v[starts_at + l + 1u];
        for (uint i = begin + gl_LocalInvocationID.x; i < end; i += gl_WorkGroupSize.x) {
            uint node = bvh_topo.v[inner_at + 3u * i];
            uint left = bvh_topo.v[inner_at + 3u * i + 1u];
            uint link = bvh_topo.v[inner_at + 3u * i + 2u];
            vec3 llo = uintBitsToFloat(imageLoad(nodes, at(2u * left)).xyz);
            vec3 lhi = uintBitsToFloat(imageLoad(nodes, at(2u * left + 1u)).xyz);
            vec3 rlo = uintBitsToFloat(imageLoad(nodes, at(2u * left + 2u)).xyz);
            vec3 rhi = uintBitsToFloat(imageLoad(nodes, at(2u * left + 3u)).xyz);
            imageStore(nodes, at(2u * node), uvec4(floatBitsToUint(min(llo, rlo)), left));
            imageStore(nodes, at(2u * node + 1u), uvec4(floatBitsToUint(max(lhi, rhi)), link));
        }
        memoryBarrierImage();
        barrier();
    }
}
