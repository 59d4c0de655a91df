#version 450
// Pass `vertex mark`: which triangles cover a pixel this frame, as a bitmap (bit t % 32 of
// word t / 32; cleared by pass `vertex list` as it reads it). Dispatched indirectly over
// the rasteriser's list of 16 x 4 tiles (glsl/raster/tiles.comp): pixels outside them hold
// no triangle. A pixel marks its key's triangle unless the pixel to its left in the tile
// holds the same one (runs of a triangle along a row then cost one atomic).
layout(local_size_x = 16, local_size_y = 4) in;
#include <common/tiles.glsl>

layout(push_constant) uniform Push {
    uint width;
    uint height;
    uint triangle_count;
    uint pad;
} pc;

layout(std430, set = 0, binding = 0) readonly buffer Keys { uvec2 k[]; } keys;
// The tile list: workgroup i marks from the 16 x 4 tile list[i] (tile_entry(tx, ty),
// glsl/common/tiles.glsl).
layout(std430, set = 0, binding = 1) readonly buffer Tiles { uint head[4]; uint list[]; } tiles;
layout(std430, set = 0, binding = 2) buffer Covered { uint w[]; } covered;

shared uint row_tri[4][16];

void main() {
    uint tile = tiles.list[gl_WorkGroupID.x];
    uvec2 lid = gl_LocalInvocationID.xy;
    uvec2 px = tile_pixel(tile, lid);
    uint tri = 0xffffffffu;
    if (all(lessThan(px, uvec2(pc.width, pc.height)))) {
        tri = keys.k[px.y * pc.width + px.x].x;
    }
    row_tri[lid.y][lid.x] = tri;
    barrier();
    // An empty key (~0) names no triangle.
    if (tri >= pc.triangle_count) return;
    if (lid.x > 0u && row_tri[lid.y][lid.x - 1u] == tri) return;
    atomicOr(covered.w[tri >> 5u], 1u << (tri & 31u));
}
