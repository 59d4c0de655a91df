#version 450
#extension GL_GOOGLE_include_directive : require
#include <common/util.glsl>
// Pass `sss reach triangles` (SssKernel::set_reach with triangle marks): every triangle with
// a texel in a block of this frame's reach is marked in the caller's triangle bitmap
// (`reach_marks`, bit first + t; the character frame's `vertex mark` bitmap, so that the
// environment's per-vertex passes shade the corners whose irradiance the texture-space
// irradiance of the reach interpolates). A triangle's texels' blocks are listed with the UV
// layout (kernels::sss::pack::reach_static); any reached one marks it.
layout(local_size_x = 64) in;

layout(push_constant) uniform Push {
    uint triangles;
    uint first;         // the bit of triangle 0 in reach_marks
} pc;

layout(std430, set = 0, binding = 22) readonly buffer ReachBlocks { uint w[]; } reach_blocks;
// The reach's per-triangle layout (kernels::sss::pack::reach_static), REACH_ROW texels a row:
// an image, as lavapipe loads a texel with one gather and a storage buffer's uvec4 at a
// per-lane index with a loop over the lanes per component.
layout(set = 0, binding = 23, rgba32ui) readonly uniform uimage2D reach_static;
const uint REACH_ROW = 1024u; // pack::BVH_ROW
layout(std430, set = 0, binding = 24) buffer ReachMarks { uint w[]; } reach_marks;

// Entry k of the reach's layout.
uvec4 reach_entry(uint k) {
    return imageLoad(reach_static, table_texel(k, REACH_ROW));
}

void main() {
    uint t = gl_GlobalInvocationID.x;
    if (t >= pc.triangles) return;
    uvec4 own = reach_entry(2u * t + 1u); // (first, k, ...): the k blocks from first
    bool hit = false;
    for (uint c = 0u; c < own.y; c++) {
        uint b = reach_entry(own.x + c).x;
        hit = hit || ((reach_blocks.w[b >> 5u] >> (b & 31u)) & 1u) != 0u;
    }
    if (hit) {
        uint m = pc.first + t;
        atomicOr(reach_marks.w[m >> 5u], 1u << (m & 31u));
    }
}
