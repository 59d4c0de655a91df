#version 450
#extension GL_GOOGLE_include_directive : require
// Taps of the compact lighting lobes (src/kernels/srbf/sharp.rs; its `taps` is the CPU twin):
// lobe j, rotated by R, puts its whole integral / pi at the texel of the W x H visibility
// grid that holds its axis. Output per lobe: two vec4, (texel centre direction xyz, texel
// index as a float), (weight rgb, 0).
layout(local_size_x = 64) in;

layout(push_constant) uniform Push {
    vec4 rot[3];   // columns of R (xyz)
    uint lobes;    // compact lobes
    uint width;
    uint height;
} pc;

layout(std430, set = 0, binding = 0) readonly buffer LobeAxes { vec4 v[]; } lobe_axes;   // xyz, sharpness
layout(std430, set = 0, binding = 1) readonly buffer LobeAmps { vec4 v[]; } lobe_amps;   // rgb
layout(std430, set = 0, binding = 2) writeonly buffer Taps { vec4 v[]; } taps;

#include "texel.glsl"

void main() {
    uint j = gl_GlobalInvocationID.x;
    if (j >= pc.lobes) return;
    mat3 R = mat3(pc.rot[0].xyz, pc.rot[1].xyz, pc.rot[2].xyz);
    vec4 a = lobe_axes.v[j];
    vec3 axis = normalize(R * a.xyz);
    uvec2 t = texel_of(axis, pc.width, pc.height);
    vec3 dir = texel_direction(t, pc.width, pc.height);
    taps.v[2u * j] = vec4(dir, float(t.y * pc.width + t.x));  // exact below 2^24 texels
    taps.v[2u * j + 1u] = vec4(lobe_amps.v[j].rgb * integral_over_pi(a.w), 0.0);
}
