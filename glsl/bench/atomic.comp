#version 450
// Atomics probe for `bench peak`: `iterations` atomicAdd per invocation on a storage buffer
// of 2^bits counters, each result used. Mode 0: every invocation of a workgroup on the same
// counter (the workgroup's own: contended); mode 1: a hashed counter each time (spread).
#include <common/util.glsl>
layout(local_size_x = 256) in;

layout(push_constant) uniform Push {
    uint n;
    uint iterations;
    uint mode;
    uint bits;
} pc;

layout(std430, set = 0, binding = 0) buffer Counters { uint c[]; } counters;
layout(std430, set = 0, binding = 1) writeonly buffer Dst { uint v[]; } dst;

void main() {
    uint i = linear_id();
    if (i >= pc.n) return;
    uint mask = (1u << pc.bits) - 1u;
    uint h = hash_u32(i);
    uint acc = 0u;
    for (uint k = 0u; k < pc.iterations; k++) {
        uint e;
        if (pc.mode != 0u) {
            h = h * 1664525u + 1013904223u;
            e = h >> (32u - pc.bits);
        } else {
            e = (gl_WorkGroupID.x + k) & mask;
        }
        acc += atomicAdd(counters.c[e], 1u);
    }
    dst.v[i] = acc;
}
