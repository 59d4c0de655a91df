#version 450
// Compact lighting lobes shadowed by rays at their exact rotated directions (pass
// `srbf sharp` with shadow rays; src/kernels/srbf/sharp.rs ray_taps and ray_bits are the CPU
// twin). One invocation per shade slot:
// - invocation j < lobes writes lobe j's tap: (w_j = normalize(R xi_j), j as a float),
//   (weight rgb = amplitude x integral / pi, 0), the layout of glsl/srbf/sharp.comp's taps
//   with the lobe index where the grid tap has its texel;
// - every slot writes its shadow bits: bit j set when n . w_j > 0 and the ray from
//   p + offset n along w_j hits no triangle of the static mesh's BVH (the rule of
//   src/geom/visibility.rs direction_visibility, the traversal of glsl/common/bvh.glsl).
// `srbf shade` reads the bits as word 0 of its visibility (bits[0 * slots + slot], bit j), so
// the shading is the grid path's, with the exact direction in the cosine and in the ray.
// A padding slot has a zero normal: no ray, no bit.
layout(local_size_x = 64) in;

layout(push_constant) uniform Push {
    vec4 rot[3];   // columns of R (xyz)
    uint lobes;    // compact lobes (<= 32)
    uint slots;
    float offset;  // ray origin offset along the normal (scene units)
} pc;

layout(std430, set = 0, binding = 0) readonly buffer LobeAxes { vec4 v[]; } lobe_axes;   // xyz, sharpness
layout(std430, set = 0, binding = 1) readonly buffer LobeAmps { vec4 v[]; } lobe_amps;   // rgb
layout(std430, set = 0, binding = 2) writeonly buffer Taps { vec4 v[]; } taps;
layout(std430, set = 0, binding = 3) readonly buffer Positions { vec4 v[]; } positions;  // per slot
layout(std430, set = 0, binding = 4) readonly buffer Normals { vec4 v[]; } normals;      // per slot
layout(std430, set = 0, binding = 5) writeonly buffer SunBits { uint v[]; } sun_bits;    // per slot
const uint BVH_ROW = 1024u;
layout(set = 0, binding = 6, rgba32ui) readonly uniform uimage2D nodes;

#include <common/bvh.glsl>
#include "texel.glsl"

void main() {
    uint slot = gl_GlobalInvocationID.x;
    mat3 R = mat3(pc.rot[0].xyz, pc.rot[1].xyz, pc.rot[2].xyz);
    if (slot < pc.lobes) {
        vec4 a = lobe_axes.v[slot];
        taps.v[2u * slot] = vec4(normalize(R * a.xyz), float(slot));
        taps.v[2u * slot + 1u] = vec4(lobe_amps.v[slot].rgb * integral_over_pi(a.w), 0.0);
    }
    if (slot >= pc.slots) return;
    vec3 n = normals.v[slot].xyz;
    vec3 o = positions.v[slot].xyz + n * pc.offset;
    float inf = uintBitsToFloat(0x7f800000u);
    uint bits = 0u;
    for (uint j = 0u; j < pc.lobes; j++) {
        vec3 w = normalize(R * lobe_axes.v[j].xyz);
        if (dot(n, w) > 0.0 && !any_hit(o, w, inf)) bits |= 1u << j;
    }
    sun_bits.v[slot] = bits;
}
