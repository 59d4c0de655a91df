#version 450
// Test kernel: writes a VkDispatchIndirectCommand (groups, 1, 1) for an indirect dispatch
// (tests/lifetimes.rs).
layout(local_size_x = 1) in;

layout(push_constant) uniform Push { uint groups; } pc;
layout(std430, set = 0, binding = 0) writeonly buffer Args { uint c[4]; } args;

void main() {
    args.c[0] = pc.groups;
    args.c[1] = 1u;
    args.c[2] = 1u;
    args.c[3] = 0u;
}
