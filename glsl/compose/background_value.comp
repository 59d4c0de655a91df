#version 450
// Pass `compose background value`: one invocation takes the frame's background pixel as the
// compose pass stores it (glsl/compose/output.glsl: the background colour, alpha 0, the
// frame's exposure), steps the frame's stamp, and dispatches pass `compose background`
// (glsl/compose/background.comp) over every tile if the pixel differs from the previous
// frame's (or was never stored), else over none: the tone mapping runs once a frame, and
// the background is stored only where it changed.
layout(local_size_x = 1) in;
#define COMPOSE_NO_OUTPUT 1
#include <compose/output.glsl>
#include <common/tiles.glsl>

// Zero when the kernel is made: no pixel stored, stamp 0.
layout(std430, set = 0, binding = 16) buffer State { Background s; } bg;

void main() {
    Params P = params.p;
    Background b = bg.s;
    vec3 r = max(P.background.rgb, vec3(0.0));
    vec4 h = vec4(r, 0.0);
    uint l = ldr_word(r, P.eye.w);
    bool same = b.stored != 0u && floatBitsToUint(h) == floatBitsToUint(b.hdr) && l == b.ldr;
    // One invocation per tile, 16 x 4 invocations a group.
    uvec2 tiles = (P.counts.xy + TILE_SIZE - 1u) / TILE_SIZE;
    uvec2 groups = (tiles + uvec2(15u, 3u)) / uvec2(16u, 4u);
    b.dispatch = same ? uvec4(0u, 1u, 1u, 0u) : uvec4(groups, 1u, 0u);
    b.hdr = h;
    b.ldr = l;
    b.stored = 1u;
    // Stamps: 0 marks a tile never listed, so no frame's stamp is 0.
    b.stamp = b.stamp == 0xffffffffu ? 1u : b.stamp + 1u;
    bg.s = b;
}
