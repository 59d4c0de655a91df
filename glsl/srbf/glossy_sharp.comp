#version 450
#extension GL_GOOGLE_include_directive : require
// Pass `srbf glossy sharp` with grid taps (glossy_sharp.glsl): each compact lobe at the
// centre of the visibility grid's texel holding its rotated axis, seen through the vertex's
// visibility bit for that texel (the diffuse path's grid tap, src/kernels/srbf/sharp.rs).
layout(local_size_x = 64) in;

#include "texel.glsl"

// Per vertex, the W x H grid's bits, vertex-major: bits[v * words + texel / 32].
layout(std430, set = 0, binding = 5) readonly buffer Visible { uint w[]; } visible;

#include "glossy_sharp.glsl"

float seen_at(uint v, vec3 x, vec3 n, vec3 axis, out vec3 w) {
    uvec2 t = texel_of(axis, pc.width, pc.height);
    w = texel_direction(t, pc.width, pc.height);
    uint texel = t.y * pc.width + t.x;
    uint words = (pc.width * pc.height + 31u) / 32u;
    return float((visible.w[v * words + texel / 32u] >> (texel % 32u)) & 1u);
}
