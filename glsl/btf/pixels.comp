#version 450
#extension GL_EXT_samplerless_texture_functions : require
// Pass `btf pixels`: the pixels `btf shade` and `btf env basis` shade this frame, listed.
// Over the rasteriser's tile list (one 16 x 4 workgroup a tile, dispatched indirectly, as the
// shading passes were): a pixel whose G-buffer tag is a part in the mask is appended to
// `pixels` (y * width + x); an empty pixel gets the background (0) in `result`, as `btf
// shade` over the tiles gave it; another part's pixel keeps what it holds. The shading
// passes then run over the list (BTF_PIXELS), 64 listed pixels a workgroup: on lavapipe a
// lane that returns early still runs the rest of the shader under its mask (a shading pass
// whose every pixel returned at once kept 70% of its time), so shading over the tiles paid
// for their empty and skin pixels too (about a third of the lanes in the character frame).
layout(local_size_x = 16, local_size_y = 4) in;
#include <common/tiles.glsl>

layout(push_constant) uniform Push {
    uvec4 dims;   // width, height, part mask (bit p: list part p; all ones: every part), 0
} pc;

// Layer 0: (position, tag), tag = 0 where empty, else +-(1 + part) (src/scene/gbuffer.rs).
layout(set = 0, binding = 4) uniform texture2DArray gbuffer;
layout(std430, set = 0, binding = 5) writeonly buffer Result { vec4 v[]; } result;
layout(std430, set = 0, binding = 6) readonly buffer Tiles { uint head[4]; uint list[]; } tiles;
// The list's head (ceil(count / 64), 1, 1, count), the shading passes' indirect command
// (the kernel resets it to (0, 1, 1, 0) before this pass), and the pixels, room for every
// pixel.
// (common/btf_pixels.glsl reads it.)
layout(std430, set = 0, binding = 16) buffer PixelHead { uint head[4]; } pixel_head;
layout(std430, set = 0, binding = 17) writeonly buffer Pixels { uint list[]; } pixels;

void main() {
    uint tile = tiles.list[gl_WorkGroupID.x];
    uvec2 px = tile_pixel(tile, pc.dims.x, gl_LocalInvocationID.xy);
    if (any(greaterThanEqual(px, pc.dims.xy))) return;
    uint k = px.y * pc.dims.x + px.x;
    float tag = texelFetch(gbuffer, ivec3(px, 0), 0).w;
    if (abs(tag) < 0.5) {
        result.v[k] = vec4(0.0);
        return;
    }
    uint part = uint(abs(tag) + 0.5) - 1u;
    if (pc.dims.z != 0xFFFFFFFFu && (part >= 32u || (pc.dims.z & (1u << part)) == 0u)) return;
    uint j = atomicAdd(pixel_head.head[3], 1u);
    // The list has a slot for every pixel: j < its length always.
    if (j < uint(pixels.list.length())) pixels.list[j] = k;
    if (j % 64u == 0u) atomicAdd(pixel_head.head[0], 1u);
}
