// Where a skin pixel looks the texture-space diffusion up, shared by compose/shade.comp (the
// lookup) and compose/need.comp (which marks the atlas segments the lookup will read, so
// that the diffusion runs only there): the pixel's ray, its barycentrics on its skin
// triangle (as raster resolve finds them) and the atlas uv they give. Twin:
// kernels::compose::cpu::shade.
#ifndef VKSHADE_COMPOSE_SKIN_UV_GLSL
#define VKSHADE_COMPOSE_SKIN_UV_GLSL

// The ray through the centre of pixel px of a size-pixel frame (the camera basis as raster
// resolve takes it: right and up pre-scaled by the half-field tangents).
vec3 pixel_ray(uvec2 px, uvec2 size, vec3 forward, vec3 right, vec3 up) {
    vec2 s = (vec2(px) + 0.5) / vec2(size) * 2.0 - 1.0;
    return normalize(forward + right * s.x - up * s.y);
}

// Barycentrics (w0, u, v) of the ray eye + t d on triangle (a, b, c), clamped into it.
vec3 skin_barycentrics(vec3 a, vec3 b, vec3 c, vec3 eye, vec3 d) {
    vec3 e1 = b - a, e2 = c - a;
    vec3 pv = cross(d, e2);
    float det = dot(e1, pv);
    vec3 tv = eye - a;
    float inv = det != 0.0 ? 1.0 / det : 0.0;
    float u = clamp(dot(tv, pv) * inv, 0.0, 1.0);
    vec3 qv = cross(tv, e1);
    float v = clamp(dot(d, qv) * inv, 0.0, 1.0 - u);
    return vec3(1.0 - u - v, u, v);
}

// The atlas uv at barycentrics bc of a skin triangle with atlas corners (uv0, uv1) = uv01,
// uv2.
vec2 skin_atlas_uv(vec4 uv01, vec2 uv2, vec3 bc) {
    return uv01.xy * bc.x + uv01.zw * bc.y + uv2 * bc.z;
}

#endif
