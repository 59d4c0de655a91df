#version 450
#extension GL_GOOGLE_include_directive : require
// Taps of the compact lighting lobes (src/kernels/srbf/sharp.rs; its `taps` is the CPU twin),
// lobe by lobe. A point source (amplitude w = 0) is one tap: its whole integral / pi at the
// texel of the W x H visibility grid that holds its rotated axis. A resolved lobe (w = 1) is
// SPREAD_TAPS taps, the 2 x 2 texels whose centres surround its axis (the texel holding it,
// then across the nearer side in u, in v, and both), sharing the integral by the lobe's
// integral over each texel (SPREAD_SUB^2 sub-samples a texel, renormalised); a tap off the
// grid or with no share is zero at the first texel. Lobe j's taps start after the taps of
// lobes 0..j-1. Output per tap: two vec4, (texel centre direction xyz, texel index as a
// float), (weight rgb, 0).
layout(local_size_x = 64) in;

layout(push_constant) uniform Push {
    vec4 rot[3];   // columns of R (xyz)
    uint lobes;    // compact lobes
    uint width;
    uint height;
} pc;

layout(std430, set = 0, binding = 0) readonly buffer LobeAxes { vec4 v[]; } lobe_axes;   // xyz, sharpness
layout(std430, set = 0, binding = 1) readonly buffer LobeAmps { vec4 v[]; } lobe_amps;   // rgb, resolved
layout(std430, set = 0, binding = 2) writeonly buffer Taps { vec4 v[]; } taps;

#include "texel.glsl"

const uint SPREAD_TAPS = 4u;   // sharp::SPREAD_TAPS
const uint SPREAD_SUB = 8u;    // sharp::SPREAD_SUB

void main() {
    uint j = gl_GlobalInvocationID.x;
    if (j >= pc.lobes) return;
    mat3 R = mat3(pc.rot[0].xyz, pc.rot[1].xyz, pc.rot[2].xyz);
    vec4 a = lobe_axes.v[j];
    vec4 amp = lobe_amps.v[j];
    vec3 axis = normalize(R * a.xyz);
    uvec2 t0 = texel_of(axis, pc.width, pc.height);
    vec2 f = texel_coords(axis, pc.width, pc.height) - vec2(t0);
    ivec2 step = ivec2(f.x < 0.5 ? -1 : 1, f.y < 0.5 ? -1 : 1);
    // The footprint; off: a row past a pole.
    uvec2 cell[SPREAD_TAPS];
    bool on[SPREAD_TAPS];
    for (uint c = 0u; c < SPREAD_TAPS; c++) {
        ivec2 d = ivec2((c & 1u) != 0u ? step.x : 0, (c & 2u) != 0u ? step.y : 0);
        int y = int(t0.y) + d.y;
        on[c] = y >= 0 && y < int(pc.height);
        cell[c] = on[c] ? uvec2(uint((int(t0.x) + d.x + int(pc.width)) % int(pc.width)), uint(y)) : t0;
    }
    vec3 weight = amp.rgb * integral_over_pi(a.w);
    float e[SPREAD_TAPS];
    float total = 0.0;
    for (uint c = 0u; c < SPREAD_TAPS; c++) {
        e[c] = 0.0;
        if (amp.w != 0.0 && on[c]) {
            uvec2 t = cell[c];
            for (uint sj = 0u; sj < SPREAD_SUB; sj++) {
                float v = (float(t.y) + (float(sj) + 0.5) / float(SPREAD_SUB)) / float(pc.height);
                float sin_theta = sin(PI * v);
                for (uint si = 0u; si < SPREAD_SUB; si++) {
                    float u = (float(t.x) + (float(si) + 0.5) / float(SPREAD_SUB)) / float(pc.width);
                    e[c] += exp(a.w * (dot(axis, direction(u, v)) - 1.0)) * sin_theta;
                }
            }
        }
        total += e[c];
    }
    bool spread = total > 0.0 && !isinf(total);
    uint base = 0u;
    for (uint i = 0u; i < j; i++) {
        base += lobe_amps.v[i].w != 0.0 ? SPREAD_TAPS : 1u;
    }
    uint count = amp.w != 0.0 ? SPREAD_TAPS : 1u;
    for (uint c = 0u; c < count; c++) {
        float share = spread ? e[c] / total : (c == 0u ? 1.0 : 0.0);
        uvec2 t = (spread && on[c] && share > 0.0) ? cell[c] : t0;
        uint k = base + c;
        taps.v[2u * k] = vec4(texel_direction(t, pc.width, pc.height), float(t.y * pc.width + t.x));  // exact below 2^24 texels
        taps.v[2u * k + 1u] = vec4(weight * share, 0.0);
    }
}
