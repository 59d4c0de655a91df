#version 450
// Pass `sss reach list` (SssKernel::set_reach): the occupied atlas segments in a block of
// this frame's reach (`reach_blocks`, written by `sss reach boxes`), listed for the
// irradiance (glsl/sss/irradiance_posed_env_listed.comp, dispatched indirectly over the
// list) as `sss needed list` lists the needed ones (glsl/sss/segment_list.glsl). It clears
// the blocks once every lane has read them (the next frame starts empty). One workgroup.
layout(local_size_x = 256) in;

layout(push_constant) uniform Push {
    uint words;        // words of the segment bitmap
    uint block_words;  // words of the block bitmap
} pc;
#include <sss/segments.glsl>

layout(std430, set = 0, binding = 19) readonly buffer Occupied { uint w[]; } occupied;
layout(std430, set = 0, binding = 22) buffer ReachBlocks { uint w[]; } reach_blocks;
layout(std430, set = 0, binding = 25) writeonly buffer ReachList { uint head[4]; uint v[]; } reach_list;

const uint BLOCK_ROWS = 4u; // kernels::sss::pack::REACH_BLOCK_ROWS

#define SEGMENT_LIST reach_list
#include <sss/segment_list.glsl>

void main() {
    uint lane = gl_LocalInvocationID.x;
    segment_list_begin();
    for (uint w = lane; w < pc.words; w += gl_WorkGroupSize.x) {
        uint bits = occupied.w[w];
        uint keep = 0u;
        if ((ROW_SEGMENTS & 31u) == 0u) {
            // Rows of whole words (atlas sizes that are multiples of 256): the word of the
            // block row holds the same 32 segment columns.
            uint row_words = ROW_SEGMENTS >> 5u;
            uint y = w / row_words;
            keep = bits & reach_blocks.w[(y / BLOCK_ROWS) * row_words + w % row_words];
        } else {
            uint scan = bits;
            while (scan != 0u) {
                uint b = uint(findLSB(scan));
                scan &= scan - 1u;
                uint seg = w * 32u + b;
                uint y = seg / ROW_SEGMENTS, sx = seg % ROW_SEGMENTS;
                uint blk = (y / BLOCK_ROWS) * ROW_SEGMENTS + sx;
                keep |= ((reach_blocks.w[blk >> 5u] >> (blk & 31u)) & 1u) << b;
            }
        }
        segment_list_append(w, keep);
    }
    memoryBarrierBuffer();
    barrier();
    for (uint w = lane; w < pc.block_words; w += gl_WorkGroupSize.x) reach_blocks.w[w] = 0u;
    if (lane == 0u) segment_list_head();
}
