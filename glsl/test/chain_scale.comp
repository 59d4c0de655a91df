#version 450
// Test kernel: y[i] = a * x[i] + b. First link of the dispatch chain in tests/pipeline.rs.
#include <common/util.glsl>
layout(local_size_x = 64) in;

layout(push_constant) uniform Push { float a; float b; uint n; } pc;
layout(std430, set = 0, binding = 0) readonly buffer Src { float x[]; } src;
layout(std430, set = 0, binding = 1) writeonly buffer Dst { float y[]; } dst;

void main() {
    uint i = linear_id();
    if (i >= pc.n) return;
    dst.y[i] = pc.a * src.x[i] + pc.b;
}
