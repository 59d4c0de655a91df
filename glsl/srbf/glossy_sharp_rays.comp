#version 450
#extension GL_GOOGLE_include_directive : require
// Pass `srbf glossy sharp` with shadow rays (glossy_sharp.glsl): each compact lobe at its
// exact rotated axis w, seen when n . w > 0 and the ray from x + offset n along w hits no
// triangle of the static mesh's BVH (glsl/srbf/sharp_rays.comp's rule and traversal).
layout(local_size_x = 64) in;

#include "texel.glsl"

const uint BVH_ROW = 1024u;
layout(set = 0, binding = 5, rgba32ui) readonly uniform uimage2D nodes;
layout(set = 0, binding = 6, rgba32ui) readonly uniform uimage2D tris;

#include <common/bvh.glsl>
#include "glossy_sharp.glsl"

float seen_at(uint v, vec3 x, vec3 n, vec3 axis, out vec3 w) {
    w = axis;
    float inf = uintBitsToFloat(0x7f800000u);
    return dot(n, w) > 0.0 && !any_hit(x + n * pc.offset, w, inf) ? 1.0 : 0.0;
}
