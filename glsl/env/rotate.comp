#version 450
// The environment's lobes rotated by the frame's rotation (src/kernels/env/gpu.rs): per lobe
// two vec4, (axis.xyz, sharpness), (amplitude.rgb, 0); axis = normalize(R axis), as
// kernels::env::cpu::rotate.
layout(local_size_x = 64) in;

layout(push_constant) uniform Push {
    vec4 c0; // the rotation's columns (xyz)
    vec4 c1;
    vec4 c2;
    uint lobe_count;
} pc;

layout(std430, set = 0, binding = 0) readonly buffer Base { vec4 l[]; } base;
layout(std430, set = 0, binding = 1) writeonly buffer Lobes { vec4 l[]; } lobes;

void main() {
    uint j = gl_GlobalInvocationID.x;
    if (j >= pc.lobe_count) return;
    vec4 a = base.l[2u * j];
    vec3 r = pc.c0.xyz * a.x + pc.c1.xyz * a.y + pc.c2.xyz * a.z;
    lobes.l[2u * j] = vec4(normalize(r), a.w);
    lobes.l[2u * j + 1u] = base.l[2u * j + 1u];
}
