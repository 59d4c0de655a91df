#version 450
#extension GL_ARB_gpu_shader_int64 : require
// Clears the visibility buffer to the empty key (all ones: farther than any depth, no
// triangle) and the counters of the frame's triangle pass.
layout(local_size_x = 64) in;

layout(push_constant) uniform Push {
    uint width;
    uint height;
} pc;

layout(std430, set = 0, binding = 0) writeonly buffer Visibility { uint64_t key[]; } vis;
layout(std430, set = 0, binding = 1) writeonly buffer Counters { uint c[8]; } counters;

void main() {
    uvec2 p = gl_GlobalInvocationID.xy;
    if (p.x < pc.width && p.y < pc.height) vis.key[p.y * pc.width + p.x] = ~0ul;
    if (p.y == 0u && p.x < 8u) counters.c[p.x] = 0u;
}
