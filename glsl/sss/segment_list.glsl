// Appending atlas segments to a list that is its own VkDispatchIndirectCommand, shared by
// passes `sss needed list` and `sss reach list` (one workgroup each). The includer defines
// SEGMENT_LIST, the list's buffer ({ uint head[4]; uint v[]; }: the head, then segments as
// x / 8 | y << 16), and ROW_SEGMENTS (glsl/sss/segments.glsl). segment_list_begin() before
// any append (every lane), segment_list_append(w, bits) for the segments of bitmap word w
// set in `bits`, at a place reserved with a shared counter, and, after a barrier,
// segment_list_head() from one lane: the consumers' 8-segment workgroups (gx, gy, 1) with
// gx * gy >= ceil(count / 8) and fewer than gy spare workgroups, and the count. The list's
// order varies with the lanes' timing.
#ifndef VKSHADE_SSS_SEGMENT_LIST_GLSL
#define VKSHADE_SSS_SEGMENT_LIST_GLSL

// Vulkan guarantees 65535 workgroups an axis (maxComputeWorkGroupCount).
const uint MAX_GROUPS = 65535u;

shared uint segment_count;

void segment_list_begin() {
    if (gl_LocalInvocationID.x == 0u) segment_count = 0u;
    barrier();
}

void segment_list_append(uint w, uint bits) {
    if (bits == 0u) return;
    uint k = atomicAdd(segment_count, uint(bitCount(bits)));
    while (bits != 0u) {
        uint seg = w * 32u + uint(findLSB(bits));
        bits &= bits - 1u;
        SEGMENT_LIST.v[k] = (seg % ROW_SEGMENTS) | ((seg / ROW_SEGMENTS) << 16u);
        k++;
    }
}

void segment_list_head() {
    uint n = segment_count;
    uint groups = (n + 7u) / 8u;
    uint gy = (groups + MAX_GROUPS - 1u) / MAX_GROUPS;
    uint gx = gy == 0u ? 0u : (groups + gy - 1u) / gy;
    SEGMENT_LIST.head[0] = gx;
    SEGMENT_LIST.head[1] = max(gy, 1u);
    SEGMENT_LIST.head[2] = 1u;
    SEGMENT_LIST.head[3] = n;
}
#endif
