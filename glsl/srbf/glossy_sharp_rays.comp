#version 450
#extension GL_GOOGLE_include_directive : require
// Pass `srbf glossy sharp` with shadow rays (glossy_sharp.glsl): each compact lobe at its
// exact rotated axis w, seen when n . w > 0 and the ray from x + offset n along w hits no
// triangle of the static mesh's BVH (glsl/srbf/sharp_rays.comp's rule and traversal).
layout(local_size_x = 64) in;

#include "texel.glsl"

layout(std430, set = 0, binding = 3) readonly buffer LobeAxes { vec4 v[]; } lobe_axes;   // xyz, sharpness
layout(std430, set = 0, binding = 4) readonly buffer LobeAmps { vec4 v[]; } lobe_amps;   // rgb
const uint BVH_ROW = 1024u;
layout(set = 0, binding = 5, rgba32ui) readonly uniform uimage2D nodes;

#include <common/bvh.glsl>
#include "glossy_sharp.glsl"

float seen_at(uint j, vec3 x, vec3 n, out vec3 w, out vec3 e) {
    vec4 a = lobe_axes.v[j];
    mat3 R = mat3(pc.rot[0].xyz, pc.rot[1].xyz, pc.rot[2].xyz);
    w = normalize(R * a.xyz);
    e = PI * integral_over_pi(a.w) * lobe_amps.v[j].rgb;
    float inf = uintBitsToFloat(0x7f800000u);
    return dot(n, w) > 0.0 && !any_hit(x + n * pc.offset, w, inf) ? 1.0 : 0.0;
}
