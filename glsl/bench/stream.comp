#version 450
// Streaming bandwidth: dst[i] = src[i] * scale over vec4s, 32 bytes moved per invocation.
#include <common/util.glsl>
layout(local_size_x = 256) in;

layout(push_constant) uniform Push { uint n; float scale; } pc;
layout(std430, set = 0, binding = 0) readonly buffer Src { vec4 v[]; } src;
layout(std430, set = 0, binding = 1) writeonly buffer Dst { vec4 v[]; } dst;

void main() {
    uint i = linear_id();
    if (i >= pc.n) return;
    dst.v[i] = src.v[i] * pc.scale;
}
