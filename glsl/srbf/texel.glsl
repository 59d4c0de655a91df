// The W x H equirectangular grid of the visibility (src/kernels/srbf/sharp.rs `taps`,
// `texel_of` and `texel_coords` are the CPU twin, in the same f32 arithmetic): a direction
// in texel units, the texel holding it, a texel's centre direction, and a lobe's integral. Shared by the compact-lobe passes
// (sharp.comp, sharp_rays.comp, glossy_sharp.comp, glossy_sharp_rays.comp).

const float PI = 3.14159265359;
const float TAU = 6.28318530718;

vec3 direction(float u, float v) {
    float theta = PI * v, phi = TAU * (u - 0.5);
    return vec3(sin(theta) * sin(phi), cos(theta), -sin(theta) * cos(phi));
}

// Unit direction `axis` in texel units of the W x H grid: (u W, v H).
vec2 texel_coords(vec3 axis, uint width, uint height) {
    float theta = atan(length(axis.xz), axis.y);
    float phi = atan(axis.x, -axis.z);
    return vec2((0.5 + phi / TAU) * float(width), theta / PI * float(height));
}

// (column, row) of the texel holding unit direction `axis`.
uvec2 texel_of(vec3 axis, uint width, uint height) {
    vec2 p = texel_coords(axis, width, height);
    uint x = uint(max(floor(p.x), 0.0)) % width;
    uint y = min(uint(max(floor(p.y), 0.0)), height - 1u);
    return uvec2(x, y);
}

// Centre direction of texel (x, y).
vec3 texel_direction(uvec2 t, uint width, uint height) {
    return direction((float(t.x) + 0.5) / float(width), (float(t.y) + 0.5) / float(height));
}

// A lobe's integral 2 pi (1 - e^(-2 lambda)) / lambda, over pi.
float integral_over_pi(float sharpness) {
    return 2.0 * (1.0 - exp(-2.0 * sharpness)) / sharpness;
}
