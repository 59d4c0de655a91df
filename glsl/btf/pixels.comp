#version 450
#extension GL_EXT_samplerless_texture_functions : require
// Pass `btf pixels`: the pixels `btf shade` and `btf env basis` shade this frame, listed.
// Over the rasteriser's tile list (one 16 x 4 workgroup a tile, dispatched indirectly, as the
// shading passes were): a pixel whose G-buffer tag is a part in the mask is appended to
// `pixels` (x | y << 16); an empty pixel gets the background (0) in `result`, as `btf
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

shared uint wg_count;
shared uint wg_base;

void main() {
    uint lid = gl_LocalInvocationIndex;
    if (lid == 0u) wg_count = 0u;
    barrier();
    uint tile = tiles.list[gl_WorkGroupID.x];
    uvec2 px = tile_pixel(tile, gl_LocalInvocationID.xy);
    bool inside = all(lessThan(px, pc.dims.xy));
    uint k = px.y * pc.dims.x + px.x;
    float tag = inside ? texelFetch(gbuffer, ivec3(px, 0), 0).w : 0.0;
    if (inside && abs(tag) < 0.5) result.v[k] = vec4(0.0);
    uint part = uint(abs(tag) + 0.5) - 1u;
    bool listed = inside && abs(tag) >= 0.5
        && (pc.dims.z == 0xFFFFFFFFu || (part < 32u && (pc.dims.z & (1u << part)) != 0u));
    // The workgroup's pixels take consecutive slots: a place in the workgroup from a shared
    // counter, then one global atomic a workgroup (lavapipe runs an atomic lane by lane).
    uint at = listed ? atomicAdd(wg_count, 1u) : 0u;
    barrier();
    if (lid == 0u) {
        uint n = wg_count;
        uint first = atomicAdd(pixel_head.head[3], n);
        wg_base = first;
        // The 64-pixel workgroups of the shading passes: ceil(count / 64), grown by the
        // multiples of 64 this workgroup's slots [first, first + n) reach past.
        uint groups = (first + n + 63u) / 64u - (first + 63u) / 64u;
        if (groups != 0u) atomicAdd(pixel_head.head[0], groups);
    }
    barrier();
    uint j = wg_base + at;
    // The list has a slot for every pixel: j < its length always.
    if (listed && j < uint(pixels.list.length())) pixels.list[j] = px.x | (px.y << 16u);
}
