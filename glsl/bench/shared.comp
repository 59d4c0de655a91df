#version 450
// Shared-memory probe for `bench peak`. Mode 0, bandwidth: 4 vec4 reads from a 256-vec4
// shared array per iteration (64 bytes per invocation; offsets move each iteration so no
// read repeats a register). Mode 1, barrier cost: per iteration one shared write, a
// workgroup barrier, one read of the neighbour's value, another barrier.
#include <common/util.glsl>
layout(local_size_x = 256) in;

layout(push_constant) uniform Push {
    uint n;           // invocations (a multiple of 256)
    uint iterations;
    uint mode;
    uint pad;
} pc;

layout(std430, set = 0, binding = 0) writeonly buffer Dst { vec4 v[]; } dst;

shared vec4 tile[256];

void main() {
    uint l = gl_LocalInvocationID.x;
    uint i = linear_id();
    tile[l] = vec4(unit_float(hash_u32(i)));
    barrier();
    vec4 sum = vec4(0.0);
    if (pc.mode == 0u) {
        for (uint k = 0u; k < pc.iterations; k++) {
            sum += tile[(l + k) & 255u] + tile[(l + k + 64u) & 255u]
                 + tile[(l + k + 128u) & 255u] + tile[(l + k + 192u) & 255u];
        }
    } else {
        for (uint k = 0u; k < pc.iterations; k++) {
            tile[l] = sum + vec4(float(k));
            barrier();
            sum += tile[(l + 1u) & 255u];
            barrier();
        }
    }
    dst.v[i] = sum;
}
