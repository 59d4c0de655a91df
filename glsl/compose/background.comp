#version 450
// Pass `compose background`, after `compose shade` over the rasteriser's listed tiles
// (glsl/compose/shade_tiles.comp), dispatched (indirectly, by pass `compose background
// value`) only on a frame whose background pixel differs from the previous frame's, or on
// the first: every tile the shade pass did not list this frame takes the background. On
// the other frames the pixels outside the listed tiles already hold it: the rasteriser's
// list holds the tiles covered this frame and those covered the frame before (stale, which
// the shade pass shades empty), so a pixel left out was background at the previous frame
// too. The shade pass stamps each tile it shades with the frame's stamp (a word per 16 x 4
// tile, glsl/common/tiles.glsl, ty * tiles_x + tx; a stamp recurs after 2^32 - 1 frames).
// Filling every pixel every frame cost 0.6-0.8 ms of the character frame's ~30 on lavapipe
// (`bench frame`; a storage-buffer store at a per-lane address runs a lane at a time).
// Invocation (tx, ty) of the dispatch takes tile (tx, ty).
layout(local_size_x = 16, local_size_y = 4) in;
#define COMPOSE_NO_OUTPUT 1
#include <compose/output.glsl>
#include <common/tiles.glsl>

layout(push_constant) uniform Push {
    uvec2 size;
} pc;

layout(std430, set = 0, binding = 11) writeonly buffer Hdr { vec4 c[]; } hdr;
layout(std430, set = 0, binding = 12) writeonly buffer Ldr { uint c[]; } ldr;
layout(std430, set = 0, binding = 16) readonly buffer State { Background s; } bg;
layout(std430, set = 0, binding = 17) readonly buffer Stamps { uint s[]; } stamps;

void main() {
    uvec2 first = gl_GlobalInvocationID.xy * TILE_SIZE;
    if (any(greaterThanEqual(first, pc.size))) return;
    Background b = bg.s;
    if (stamps.s[gl_GlobalInvocationID.y * tiles_across(pc.size.x) + gl_GlobalInvocationID.x]
        == b.stamp) return;
    uvec2 end = min(first + TILE_SIZE, pc.size);
    for (uint y = first.y; y < end.y; y++) {
        for (uint x = first.x; x < end.x; x++) {
            uint idx = y * pc.size.x + x;
            hdr.c[idx] = b.hdr;
            ldr.c[idx] = b.ldr;
        }
    }
}
