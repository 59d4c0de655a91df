#version 450
// Test kernel: dst = src * a + b per texel, between two storage images (ping-pong).
layout(local_size_x = 8, local_size_y = 8) in;

layout(push_constant) uniform Push { uvec2 size; float a; float b; } pc;
layout(set = 0, binding = 0, rgba32f) readonly uniform image2D src;
layout(set = 0, binding = 1, rgba32f) writeonly uniform image2D dst;

void main() {
    ivec2 p = ivec2(gl_GlobalInvocationID.xy);
    if (any(greaterThanEqual(uvec2(p), pc.size))) return;
    imageStore(dst, p, imageLoad(src, p) * pc.a + pc.b);
}
