#version 450
// Which atlas texels this frame's compose pass will read (pass `compose need`), so that the
// texture-space diffusion runs only there: per skin pixel of the G-buffer, the atlas uv the
// compose pass looks the diffusion up at (glsl/compose/skin_uv.glsl, the same arithmetic),
// and the 8x1 row segments of the texels around it are marked in a bitmap (bit s of word
// s / 32, segment s = y * ceil(atlas / 8) + x / 8). The lookup reads the 2 x 2 texels at
// floor(uv * atlas - 0.5); here that floor is taken at t - MARGIN and at t + MARGIN, so a
// coordinate within MARGIN of a texel boundary marks the texels on both sides of it (a 3-texel
// span) and any rounding difference between the two passes' uv (far below MARGIN) still
// finds its texels marked. The bitmap is cleared each frame before this pass.
// A pixel is skin where its key names a skin triangle (an empty key, ~0, names none).
// Dispatched indirectly over a list of 16 x 4 tiles holding every skin pixel: the
// rasteriser's list of covered tiles (glsl/raster/tiles.comp), or its tiles with a skin pixel
// (glsl/compose/classify.comp), as the character frame passes.
layout(local_size_x = 16, local_size_y = 4) in;
#include <common/tiles.glsl>

layout(push_constant) uniform Push {
    vec4 eye;       // xyz camera position (model units)
    vec4 forward;   // the camera basis as raster resolve takes it
    vec4 right;     // right * tan_x
    vec4 up;        // up * tan_y
    uvec4 counts;   // width, height, atlas size, skin triangles
} pc;

layout(std430, set = 0, binding = 1) readonly buffer Keys { uvec2 k[]; } keys;
layout(std430, set = 0, binding = 2) readonly buffer Positions { vec4 p[]; } pos;
// Per skin triangle: vertex ids (xyz), then atlas uv of corners 0, 1 (one vec4) and 2.
layout(std430, set = 0, binding = 3) readonly buffer SkinTris { uvec4 v[]; } skin_tris;
layout(std430, set = 0, binding = 4) readonly buffer SkinUvs { vec4 uv[]; } skin_uvs;
layout(std430, set = 0, binding = 5) buffer Needed { uint w[]; } needed;
// The tile list: workgroup i marks from the 16 x 4 tile list[i] (tile_entry(tx, ty),
// glsl/common/tiles.glsl).
layout(std430, set = 0, binding = 6) readonly buffer Tiles { uint head[4]; uint list[]; } tiles;

#include <compose/skin_uv.glsl>

// Texels: kernels::compose::cpu::NEED_MARGIN.
const float MARGIN = 0.01;

void main() {
    uint tile = tiles.list[gl_WorkGroupID.x];
    uvec2 px = tile_pixel(tile, gl_LocalInvocationID.xy);
    if (any(greaterThanEqual(px, pc.counts.xy))) return;
    uint tri = keys.k[px.y * pc.counts.x + px.x].x;
    // Background or cloth: the compose pass reads no diffusion there.
    if (tri >= pc.counts.w) return;
    vec3 d = pixel_ray(px, pc.counts.xy, pc.forward.xyz, pc.right.xyz, pc.up.xyz);
    uvec4 t = skin_tris.v[tri];
    vec3 bc = skin_barycentrics(pos.p[t.x].xyz, pos.p[t.y].xyz, pos.p[t.z].xyz, pc.eye.xyz, d);
    vec2 uv = skin_atlas_uv(skin_uvs.uv[2u * tri], skin_uvs.uv[2u * tri + 1u].xy, bc);
    int n = int(pc.counts.z);
    // Clamped before the conversion: a uv far outside [0, 1] (or NaN) marks the border.
    vec2 tc = uv * float(n) - 0.5;
    vec2 lo = clamp(floor(tc - MARGIN), vec2(-2.0), vec2(float(n) + 1.0));
    vec2 hi = clamp(floor(tc + MARGIN), vec2(-2.0), vec2(float(n) + 1.0));
    ivec2 a = clamp(ivec2(lo), ivec2(0), ivec2(n - 1));
    ivec2 b = clamp(ivec2(hi) + 1, ivec2(0), ivec2(n - 1));
    uint segs = uint(n + 7) / 8u;
    int x0 = a.x / 8, x1 = b.x / 8;
    for (int y = a.y; y <= b.y; y++) {
        for (int sx = x0; sx <= x1; sx++) {
            uint seg = uint(y) * segs + uint(sx);
            atomicOr(needed.w[seg >> 5u], 1u << (seg & 31u));
        }
    }
}
