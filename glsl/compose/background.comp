#version 450
// Pass `compose background`: every pixel takes the background pixel that pass `compose
// background value` (glsl/compose/background_value.comp) stored, before `compose shade`
// shades the rasteriser's covered tiles (glsl/compose/shade_tiles.comp).
layout(local_size_x = 16, local_size_y = 4) in;

layout(push_constant) uniform Push {
    uvec2 size;
} pc;

layout(std430, set = 0, binding = 11) writeonly buffer Hdr { vec4 c[]; } hdr;
layout(std430, set = 0, binding = 12) writeonly buffer Ldr { uint c[]; } ldr;
layout(std430, set = 0, binding = 16) readonly buffer BackgroundHdr { vec4 c[]; } bg_hdr;
layout(std430, set = 0, binding = 17) readonly buffer BackgroundLdr { uint c[]; } bg_ldr;

void main() {
    uvec2 px = gl_GlobalInvocationID.xy;
    if (any(greaterThanEqual(px, pc.size))) return;
    uint idx = px.y * pc.size.x + px.x;
    hdr.c[idx] = bg_hdr.c[0];
    ldr.c[idx] = bg_ldr.c[0];
}
