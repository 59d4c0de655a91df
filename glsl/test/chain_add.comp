#version 450
// Test kernel: acc[i] = acc[i] * c + y[i] (reads what chain_scale wrote; read-modify-write).
#include <common/util.glsl>
layout(local_size_x = 64) in;

layout(push_constant) uniform Push { float c; uint n; } pc;
layout(std430, set = 0, binding = 0) readonly buffer Y { float y[]; } ybuf;
layout(std430, set = 0, binding = 1) buffer Acc { float acc[]; } accbuf;

void main() {
    uint i = linear_id();
    if (i >= pc.n) return;
    accbuf.acc[i] = accbuf.acc[i] * pc.c + ybuf.y[i];
}
