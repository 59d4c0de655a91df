#version 450
#extension GL_GOOGLE_include_directive : require
// Pass `srbf glossy sharp` with grid taps (glossy_sharp.glsl): each compact lobe at the
// centres of the 2 x 2 visibility grid texels around its rotated axis, seen
// through the vertex's visibility bit for each (the diffuse path's grid taps,
// src/kernels/srbf/sharp.rs; `lobes` counts the taps, sharp::tap_count).
// The taps come from pass `srbf sharp` (glsl/srbf/sharp.comp), once per frame, through a
// uniform buffer read at uniform indices (scalar loads on lavapipe): computing them per
// vertex (two atan and four sin/cos per lane) made this pass 2.0 ms on the bunny.
layout(local_size_x = 64) in;

#include "texel.glsl"

const uint MAX_TAPS = 128u;   // pack::MAX_TAPS: sharp::MAX_LOBES x sharp::SPREAD_TAPS
// Two vec4 per tap: (texel centre direction xyz, texel index as a float), (share of the
// lobe's integral / pi x amplitude rgb, 0).
layout(std140, set = 0, binding = 3) uniform Taps { vec4 v[2u * MAX_TAPS]; } taps;
// Per vertex, the W x H grid's bits, vertex-major: bits[v * words + texel / 32].
layout(std430, set = 0, binding = 4) readonly buffer Visible { uint w[]; } visible;

#include "glossy_sharp.glsl"

float seen_at(uint j, vec3 x, vec3 n, out vec3 w, out vec3 e) {
    vec4 d = taps.v[2u * j];
    w = d.xyz;
    e = PI * taps.v[2u * j + 1u].rgb;
    uint texel = uint(d.w);
    uint v = gl_GlobalInvocationID.x;
    return float((visible.w[v * pc.words + texel / 32u] >> (texel % 32u)) & 1u);
}
