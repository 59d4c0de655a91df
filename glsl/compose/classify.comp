#version 450
// Pass `compose classify`: the rasteriser's listed tiles (glsl/raster/tiles.comp) split in
// two lists, the tiles holding a skin pixel (a key naming a skin triangle: the skin parts
// come first in the character's mesh) and the others, so that `compose shade` runs the skin's
// shading only over the first (glsl/compose/shade.glsl, its SKIN constant). On lavapipe the
// body of an `if` runs under a lane mask even when no lane takes it, so the skin's path
// (its lookups, both specular terms, a loop over the lobes) cost every cloth and empty pixel
// as much as a skin pixel: `compose shade` 2.5 ms with the skin path in place and no pixel
// taking it, 1.15 ms with it compiled out (`bench frame`, fastest of 4 alternated runs).
// One invocation per listed tile (the grid covers every tile of the image; invocations past
// the list's length return), which reads its tile's 64 keys and appends the tile to one
// list: no barrier, two atomics a tile. Each list is (head, entries): head (count, 1, 1,
// count), the indirect command of one workgroup a tile followed by the entry count, as every
// GPU-appended list (kernels::EMPTY_LIST_HEAD), reset to (0, 1, 1, 0) before this pass; the
// entries as the rasteriser's (tile_entry(tx, ty), glsl/common/tiles.glsl), in no fixed
// order.
layout(local_size_x = 64) in;
#include <common/tiles.glsl>

layout(push_constant) uniform Push {
    uvec4 dims;   // width, height, skin triangles, 0
} pc;

layout(std430, set = 0, binding = 1) readonly buffer Keys { uvec2 k[]; } keys;
layout(std430, set = 0, binding = 15) readonly buffer Tiles { uint head[4]; uint list[]; } tiles;
layout(std430, set = 0, binding = 17) buffer Plain { uint head[4]; uint list[]; } plain;
layout(std430, set = 0, binding = 18) buffer Skin { uint head[4]; uint list[]; } skin;

void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i >= tiles.head[0]) return;
    uint e = tiles.list[i];
    uvec2 origin = tile_pixel(e, uvec2(0u));
    bool has_skin = false;
    // The tile's pixels row by row (TILE_SIZE 16 x 4: a mask and a shift, no division; the
    // loop bound and the mask agree only for that size), those past the
    // image's right or bottom edge skipped; the loop ends when every lane found a skin pixel
    // or read its whole tile. An empty key (~0) names no triangle.
    for (uint p = 0u; p < TILE_SIZE.x * TILE_SIZE.y && !has_skin; p++) {
        uvec2 px = origin + uvec2(p & 15u, p >> 4u);
        if (all(lessThan(px, pc.dims.xy))) {
            has_skin = keys.k[px.y * pc.dims.x + px.x].x < pc.dims.z;
        }
    }
    // The slot from the entry count, and a workgroup more for the pass over the list.
    if (has_skin) {
        skin.list[atomicAdd(skin.head[3], 1u)] = e;
        atomicAdd(skin.head[0], 1u);
    } else {
        plain.list[atomicAdd(plain.head[3], 1u)] = e;
        atomicAdd(plain.head[0], 1u);
    }
}
