#version 450
// Test kernel, dispatched indirectly over the command it also reads as storage: every
// invocation writes the workgroup count it finds there plus `add` (tests/lifetimes.rs).
layout(local_size_x = 64) in;

layout(push_constant) uniform Push { uint add; } pc;
layout(std430, set = 0, binding = 0) readonly buffer Args { uint c[4]; } args;
layout(std430, set = 0, binding = 1) writeonly buffer Out { uint v[]; } dst;

void main() {
    dst.v[gl_GlobalInvocationID.x] = args.c[0] + pc.add;
}
