#version 450
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

const float PI = 3.14159265359;
const float TAU = 6.28318530718;

vec3 direction(float u, float v) {
    float theta = PI * v, phi = TAU * (u - 0.5);
    return vec3(sin(theta) * sin(phi), cos(theta), -sin(theta) * cos(phi));
}

void main() {
    uint j = gl_GlobalInvocationID.x;
    if (j >= pc.lobes) return;
    mat3 R = mat3(pc.rot[0].xyz, pc.rot[1].xyz, pc.rot[2].xyz);
    vec4 a = lobe_axes.v[j];
    vec3 axis = normalize(R * a.xyz);
    float theta = atan(length(axis.xz), axis.y);
    float phi = atan(axis.x, -axis.z);
    uint x = uint(max(floor((0.5 + phi / TAU) * float(pc.width)), 0.0)) % pc.width;
    uint y = min(uint(max(floor(theta / PI * float(pc.height)), 0.0)), pc.height - 1u);
    // The lobe's integral 2 pi (1 - e^(-2 lambda)) / lambda, over pi.
    float scale = 2.0 * (1.0 - exp(-2.0 * a.w)) / a.w;
    vec3 dir = direction((float(x) + 0.5) / float(pc.width), (float(y) + 0.5) / float(pc.height));
    taps.v[2u * j] = vec4(dir, float(y * pc.width + x));  // exact below 2^24 texels
    taps.v[2u * j + 1u] = vec4(lobe_amps.v[j].rgb * scale, 0.0);
}
