#version 450
// Test kernel: one mip step: dst (size/2) = mean of each 2x2 block of src. Bound to two
// single-mip views of one image, it exercises per-mip barriers.
layout(local_size_x = 8, local_size_y = 8) in;

layout(push_constant) uniform Push { uvec2 dst_size; } pc;
layout(set = 0, binding = 0, rgba32f) readonly uniform image2D src;
layout(set = 0, binding = 1, rgba32f) writeonly uniform image2D dst;

void main() {
    ivec2 p = ivec2(gl_GlobalInvocationID.xy);
    if (any(greaterThanEqual(uvec2(p), pc.dst_size))) return;
    ivec2 s = 2 * p;
    vec4 sum = imageLoad(src, s) + imageLoad(src, s + ivec2(1, 0)) + imageLoad(src, s + ivec2(0, 1))
        + imageLoad(src, s + ivec2(1, 1));
    imageStore(dst, p, 0.25 * sum);
}
