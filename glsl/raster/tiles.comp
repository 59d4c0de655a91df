#version 450
// The tile list of a frame, from the flags the visibility pass set on every 16 x 4 tile
// holding a covered pixel. One workgroup (no global counter to reset between frames).
// The list (`tiles.list`, entries tile_entry(tx, ty) = tx | ty << 16, glsl/common/tiles.glsl;
// the flags are indexed ty * tiles_x + tx) holds, in this order:
//   [0, covered):         the tiles covered this frame (flag set; the flags are cleared);
//   [covered, length):    the tiles covered last frame and not this one ("stale"), whose
//                          G-buffer and shaded pixels the tile passes reset to empty.
// head = (length, 1, 1, covered): a VkDispatchIndirectCommand of one workgroup per listed
// tile, and the covered count the next frame's clear and stale tiles start from. Words
// [tiles, 2 tiles) of the list are scratch for the stale tiles. Order within each part is
// not deterministic (shared atomics); each tile is listed once.
layout(local_size_x = 256) in;
#include <common/tiles.glsl>

layout(push_constant) uniform Push {
    uvec4 dims;  // width, height, tiles_x, tiles_y
} pc;

layout(std430, set = 0, binding = 0) buffer Flags { uint f[]; } flags;
layout(std430, set = 0, binding = 1) buffer Tiles { uint head[4]; uint list[]; } tiles;

shared uint n_stale;
shared uint n_covered;

void main() {
    uint n = pc.dims.z * pc.dims.w;
    uint lid = gl_LocalInvocationIndex;
    if (lid == 0u) {
        n_stale = 0u;
        n_covered = 0u;
    }
    uint previous = tiles.head[3];
    barrier();
    for (uint i = lid; i < previous; i += 256u) {
        uint e = tiles.list[i];
        uint t = (e >> 16u) * pc.dims.z + (e & 0xffffu);
        if (flags.f[t] == 0u) tiles.list[n + atomicAdd(n_stale, 1u)] = e;
    }
    memoryBarrierBuffer();
    barrier();
    for (uint t = lid; t < n; t += 256u) {
        if (flags.f[t] != 0u) {
            flags.f[t] = 0u;
            tiles.list[atomicAdd(n_covered, 1u)] = tile_entry(t % pc.dims.z, t / pc.dims.z);
        }
    }
    memoryBarrierBuffer();
    barrier();
    uint covered = n_covered, stale = n_stale;
    for (uint i = lid; i < stale; i += 256u) tiles.list[covered + i] = tiles.list[n + i];
    if (lid == 0u) {
        tiles.head[0] = covered + stale;
        tiles.head[1] = 1u;
        tiles.head[2] = 1u;
        tiles.head[3] = covered;
    }
}
