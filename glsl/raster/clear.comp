#version 450
#extension GL_ARB_gpu_shader_int64 : require
// Clears the visibility buffer to the empty key (all ones: farther than any depth, no
// triangle) and the counters of the frame's triangle pass. Two modes (dims.z):
//   0: every pixel, one invocation each on a 2D grid;
//   1: only the tiles the previous frame covered (the first head[3] entries of the tile
//      list `raster tiles` wrote; every other key is empty already), each workgroup
//      walking the list with a stride of dims.w workgroups, one invocation per pixel of a
//      16 x 4 tile.
// Workgroup 0 also clears the counters.
layout(local_size_x = 64) in;
#include <common/tiles.glsl>

layout(push_constant) uniform Push {
    uvec4 dims;  // width, height, mode, workgroups (mode 1)
} pc;

layout(std430, set = 0, binding = 0) writeonly buffer Visibility { uint64_t key[]; } vis;
layout(std430, set = 0, binding = 1) writeonly buffer Counters { uint c[8]; } counters;
// head: (list length, 1, 1, covered tiles); list: tile entries (tile_entry(tx, ty),
// glsl/common/tiles.glsl).
layout(std430, set = 0, binding = 2) readonly buffer Tiles { uint head[4]; uint list[]; } tiles;

void main() {
    if (gl_WorkGroupID.x == 0u && gl_WorkGroupID.y == 0u && gl_LocalInvocationID.x < 8u)
        counters.c[gl_LocalInvocationID.x] = 0u;
    if (pc.dims.z == 0u) {
        uvec2 p = gl_GlobalInvocationID.xy;
        if (p.x < pc.dims.x && p.y < pc.dims.y) vis.key[p.y * pc.dims.x + p.x] = ~0ul;
        return;
    }
    uvec2 local = uvec2(gl_LocalInvocationID.x % 16u, gl_LocalInvocationID.x / 16u);
    uint covered = tiles.head[3];
    for (uint i = gl_WorkGroupID.x; i < covered; i += pc.dims.w) {
        uint t = tiles.list[i];
        uvec2 p = tile_pixel(t, local);
        if (p.x < pc.dims.x && p.y < pc.dims.y) vis.key[p.y * pc.dims.x + p.x] = ~0ul;
    }
}
