// The pixel list of pass `btf pixels` (glsl/btf/pixels.comp, which writes it) as `btf shade`
// (common/btf_shade.glsl) and `btf env basis` (btf/env_basis.glsl) read it: with BTF_PIXELS,
// 64 listed pixels a workgroup, dispatched indirectly by the list's head; without, one
// invocation per pixel in 16 x 4 workgroups.
#ifndef VKSHADE_BTF_PIXELS_GLSL
#define VKSHADE_BTF_PIXELS_GLSL
#ifdef BTF_PIXELS
layout(local_size_x = 64) in;
// The masked parts' pixels (x | y << 16: a pixel's coordinates without dividing by the width,
// a push-constant value, which lavapipe does lane by lane; pass `btf pixels` also gave the
// tiles' empty ones their background): pixels outside the list keep what they hold.
layout(std430, set = 0, binding = 16) readonly buffer PixelHead { uint head[4]; } pixel_head;
layout(std430, set = 0, binding = 17) readonly buffer Pixels { uint list[]; } pixels;
#else
// 16 x 4: on lavapipe (8 lanes along x) 20% less CPU time than 8 x 8 for `btf shade`'s
// `block` (4 x 8: 2x more).
layout(local_size_x = 16, local_size_y = 4) in;
#endif

// The pixel this invocation shades, of an image `size` pixels; false for none.
bool shaded_pixel(uvec2 size, out uvec2 px) {
#ifdef BTF_PIXELS
    uint i = gl_GlobalInvocationID.x;
    px = uvec2(0u);
    if (i >= min(pixel_head.head[3], uint(pixels.list.length()))) return false;
    uint k = pixels.list[i];
    px = uvec2(k & 0xffffu, k >> 16u);
#else
    px = gl_GlobalInvocationID.xy;
#endif
    return all(lessThan(px, size));
}
#endif
