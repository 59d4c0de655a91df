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
// appends their segments (x / 8 | y << 16, the tile list's form) at a place reserved with a
// shared counter; then lane 0 writes the head: the VkDispatchIndirectCommand of the
// diffusion's 8-segment workgroups, (gx, gy, 1) with gx * gy >= ceil(count / 8) and fewer
// than gy spare workgroups, and the count. The list's order varies with the lanes' timing;
// each segment's texels are written by the one lane that shades them, so the output does not.
layout(local_size_x = 256) in;

layout(push_constant) uniform Push {
    uint words;        // bitmap words
    uint row_segments; // ceil(atlas size / 8)
} pc;

layout(std430, set = 0, binding = 8) readonly buffer Needed { uint w[]; } needed;
layout(std430, set = 0, binding = 19) readonly buffer Occupied { uint w[]; } occupied;
layout(std430, set = 0, binding = 20) writeonly buffer NeededList { uint head[4]; uint v[]; } needed_list;

// Vulkan guarantees 65535 workgroups an axis (maxComputeWorkGroupCount).
const uint MAX_GROUPS = 65535u;

shared uint count;

void main() {
    uint lane = gl_LocalInvocationID.x;
    if (lane == 0u) count = 0u;
    barrier();
    for (uint w = lane; w < pc.words; w += gl_WorkGroupSize.x) {
        uint bits = needed.w[w] & occupied.w[w];
        if (bits == 0u) continue;
        uint k = atomicAdd(count, uint(bitCount(bits)));
        while (bits != 0u) {
            uint seg = w * 32u + uint(findLSB(bits));
            bits &= bits - 1u;
            needed_list.v[k] = (seg % pc.row_segments) | ((seg / pc.row_segments) << 16u);
            k++;
        }
    }
    barrier();
    if (lane == 0u) {
        uint n = count;
        uint groups = (n + 7u) / 8u;
        uint gy = (groups + MAX_GROUPS - 1u) / MAX_GROUPS;
        uint gx = gy == 0u ? 0u : (groups + gy - 1u) / gy;
        needed_list.head[0] = gx;
        needed_list.head[1] = max(gy, 1u);
        needed_list.head[2] = 1u;
        needed_list.head[3] = n;
    }
}
