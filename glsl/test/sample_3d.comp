#version 450
// Test kernel: samples a 3D texture (combined image sampler) at the normalized positions
// in `points` (xyz), writing the red channel to `values`.
layout(local_size_x = 64) in;

layout(push_constant) uniform Push { uint n; } pc;
layout(set = 0, binding = 0) uniform sampler3D vol;
layout(std430, set = 0, binding = 1) readonly buffer Points { vec4 p[]; } points;
layout(std430, set = 0, binding = 2) writeonly buffer Values { float v[]; } values;

void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i >= pc.n) return;
    values.v[i] = textureLod(vol, points.p[i].xyz, 0.0).r;
}
