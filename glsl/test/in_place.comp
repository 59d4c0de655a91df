#version 450
// Test kernel: y[i] = a * x[i] + b with the write binding declared before the read binding,
// so that one buffer bound to both is a write then a read of the same resource in binding
// order (tests/safe_api.rs, a_buffer_bound_twice_is_one_use).
#include <common/util.glsl>
layout(local_size_x = 64) in;

layout(push_constant) uniform Push { float a; float b; uint n; } pc;
layout(std430, set = 0, binding = 0) writeonly buffer Dst { float y[]; } dst;
layout(std430, set = 0, binding = 1) readonly buffer Src { float x[]; } src;

void main() {
    uint i = linear_id();
    if (i >= pc.n) return;
    dst.y[i] = pc.a * src.x[i] + pc.b;
}
