#version 450
// Uniform-buffer probe for `bench peak`: `loads` vec4 reads per invocation from a 16 KiB
// uniform buffer at a dynamic index: uniform across the workgroup (mode 0: a function of the
// loop counter and a push constant) or per lane (mode 1: hashed per invocation).
#include <common/util.glsl>
layout(local_size_x = 256) in;

layout(push_constant) uniform Push {
    uint n;      // invocations
    uint loads;  // reads per invocation
    uint mode;   // 0: uniform index, 1: per-lane index
    uint seed;
} pc;

layout(std140, set = 0, binding = 0) uniform Table { vec4 v[1024]; } table;
layout(std430, set = 0, binding = 1) writeonly buffer Dst { vec4 v[]; } dst;

void main() {
    uint i = linear_id();
    if (i >= pc.n) return;
    uint h = hash_u32(i ^ pc.seed);
    vec4 sum = vec4(0.0);
    for (uint k = 0u; k < pc.loads; k++) {
        uint e;
        if (pc.mode != 0u) {
            h = h * 1664525u + 1013904223u;
            e = h >> 22u;
        } else {
            e = (k * 7u + pc.seed) & 1023u;
        }
        sum += table.v[e];
    }
    dst.v[i] = sum;
}
