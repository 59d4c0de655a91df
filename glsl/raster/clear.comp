#version 450
#extension GL_ARB_gpu_shader_int64 : require
// Clears the visibility buffer to the empty key (all ones: farther than any depth, no
// triangle) and the counters of the frame's triangle pass.
layout(local_size_x = 64) in;

layout(push_constant) uniform Push {
    uint pixels;
} pc;

layout(std430, set = 0, binding = 0) writeonly buffer Visibility { uint64_t key[]; } vis;
layout(std430, set = 0, binding = 1) writeonly buffer Counters { uint c[8]; } counters;

void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i < pc.pixels) vis.key[i] = ~0ul;
    if (i < 8u) counters.c[i] = 0u;
}
