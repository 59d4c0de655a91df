// The lights of the skin's texture-space passes (glsl/sss/vertex_light.comp,
// glsl/sss/irradiance.glsl): the block at binding 3 and each light's direction, reach and
// strength at a point (src/kernels/sss/cpu.rs Light::arriving_at, the same operations). The
// includer's push constants hold `bias`, the shadow-ray origin's offset along the normal (mm).
#ifndef VKSHADE_SSS_LIGHTS_GLSL
#define VKSHADE_SSS_LIGHTS_GLSL
const uint MAX_LIGHTS = 16u; // cpu::MAX_LIGHTS
// Two vec4 a light: (direction towards it, 0) or (position, 1); (strength, 0, 0, 0). A uniform
// buffer: lavapipe reads it at the loop's uniform index as a scalar (a storage buffer would
// be loaded lane by lane, component by component).
layout(std140, set = 0, binding = 3) uniform Lights { vec4 v[2 * MAX_LIGHTS]; } lights;

// Light l at p (normal n): its direction, the shadow ray's reach and its strength there (a
// point light's falls off with distance); returns n . dir.
float light_at(uint l, vec3 p, vec3 n, out vec3 dir, out float tmax, out float strength) {
    vec4 a = lights.v[2u * l];
    strength = lights.v[2u * l + 1u].x;
    if (a.w == 0.0) {
        dir = a.xyz;
        tmax = uintBitsToFloat(0x7f800000u);
    } else {
        vec3 dd = a.xyz - p;
        float dist = length(dd);
        dir = dd / dist;
        tmax = dist - pc.bias;
        strength = strength / (dist * dist);
    }
    return dot(n, dir);
}
#endif
