#version 450
// Pass `sss needed list`: the occupied atlas segments a caller's bitmap marks (SssKernel::
// set_needed_segments; the character frame's `compose need`), listed for the diffusion
// (glsl/sss/diffusion_env_listed.comp), which is dispatched indirectly over the list. On
// lavapipe a SIMD step whose lanes all return early still runs the rest of the shader under
// an empty mask (gallivm's `if` masks, it does not branch), so the diffusion over every
// occupied segment with the unmarked ones skipped paid about half its time for segments it
// did not shade.
//
// One workgroup: each lane takes bitmap words w = lane, lane + 256, ..., keeps the marked
// bits that are occupied (the occupied segments' bitmap, uploaded with the tile list) and
// appends their segments (x / 8 | y << 16, the tile list's form); then lane 0 writes the
// head, the diffusion's VkDispatchIndirectCommand and the count (glsl/sss/segment_list.glsl).
// The list's order varies with the lanes' timing; each segment's texels are written by the
// one lane that shades them, so the output does not.
layout(local_size_x = 256) in;

layout(push_constant) uniform Push {
    uint words;        // bitmap words
} pc;
#include <sss/segments.glsl>

layout(std430, set = 0, binding = 8) readonly buffer Needed { uint w[]; } needed;
layout(std430, set = 0, binding = 19) readonly buffer Occupied { uint w[]; } occupied;
layout(std430, set = 0, binding = 20) writeonly buffer NeededList { uint head[4]; uint v[]; } needed_list;

#define SEGMENT_LIST needed_list
#include <sss/segment_list.glsl>

void main() {
    uint lane = gl_LocalInvocationID.x;
    segment_list_begin();
    for (uint w = lane; w < pc.words; w += gl_WorkGroupSize.x) {
        segment_list_append(w, needed.w[w] & occupied.w[w]);
    }
    barrier();
    if (lane == 0u) segment_list_head();
}
