// The compose passes' parameters and output (glsl/compose/shade.glsl, background.comp): the
// frame's parameter block (kernels::compose::pack::FrameParams::bytes), the linear HDR and
// tone-mapped sRGB outputs, and the one way a pixel's radiance is stored in both
// (COMPOSE_NO_OUTPUT: the tone mapping without the outputs' buffers).
#ifndef VKSHADE_COMPOSE_OUTPUT_GLSL
#define VKSHADE_COMPOSE_OUTPUT_GLSL

struct Params {
    vec4 eye;       // xyz camera position (model units), w exposure
    vec4 forward;   // the camera basis as raster resolve takes it
    vec4 right;     // right * tan_x
    vec4 up;        // up * tan_y
    vec4 light_dir[2]; // towards the light (unit), w 0
    vec4 light_rgb[2]; // irradiance on a surface facing the light
    vec4 skin;      // rho_s, Beckmann m, F0, 0
    vec4 background; // rgb behind the character, w unused
    uvec4 counts;   // width, height, lights, lobes
    uvec4 atlas;    // atlas size, skin triangles, visibility mode (0 none, 1 per lobe), surfaces
};

layout(std430, set = 0, binding = 10) readonly buffer FrameParams { Params p; } params;

// What pass `compose background value` keeps between frames (binding 16 of the background
// passes; glsl/compose/background.comp has the method): the arguments of pass `compose
// background` (a VkDispatchIndirectCommand: every pixel on a frame whose background pixel
// differs from the previous frame's, else none), the background pixel as `store_pixel`
// stores it, and whether it was ever stored.
struct Background {
    uvec4 dispatch;
    vec4 hdr;
    uint ldr;
    uint stored;
    uint unused0;
    uint unused1;
};

vec3 aces(vec3 x) {
    return clamp((x * (2.51 * x + 0.03)) / (x * (2.43 * x + 0.59) + 0.14), 0.0, 1.0);
}

float srgb(float c) {
    return c <= 0.0031308 ? 12.92 * c : 1.055 * pow(c, 1.0 / 2.4) - 0.055;
}

// The RGBA8 word of radiance r >= 0: exposure, the ACES fit and sRGB encoding.
uint ldr_word(vec3 r, float exposure) {
    vec3 mapped = aces(r * exposure);
    uvec3 q = uvec3(round(vec3(srgb(mapped.r), srgb(mapped.g), srgb(mapped.b)) * 255.0));
    return q.r | (q.g << 8) | (q.b << 16) | (255u << 24);
}

#ifndef COMPOSE_NO_OUTPUT
layout(std430, set = 0, binding = 11) writeonly buffer Hdr { vec4 c[]; } hdr;
layout(std430, set = 0, binding = 12) writeonly buffer Ldr { uint c[]; } ldr;

// Pixel idx: radiance (clamped at 0) and alpha into the HDR buffer, its word
// (`ldr_word`) into the LDR buffer.
void store_pixel(uint idx, vec3 radiance, float alpha, float exposure) {
    radiance = max(radiance, vec3(0.0));
    hdr.c[idx] = vec4(radiance, alpha);
    ldr.c[idx] = ldr_word(radiance, exposure);
}
#endif

#endif
