#version 450
// Sampling-rate probe for `bench peak`, 3D: as sample2d.comp, from a 3D texture. Coherent:
// the grid covers neighbouring texels of one slice and each call moves to the next slice;
// random: a hashed coordinate anywhere in the volume.
#include <common/util.glsl>
layout(local_size_x = 16, local_size_y = 16) in;

layout(push_constant) uniform Push {
    uvec4 dims;  // grid width, grid height, calls per invocation, random
    vec4 scale;  // xyz: one texel in uvw
} pc;

layout(set = 0, binding = 0) uniform texture3D tex;
layout(set = 0, binding = 1) uniform sampler smp;
layout(std430, set = 0, binding = 2) writeonly buffer Result { vec4 v[]; } result;

void main() {
    uvec2 p = gl_GlobalInvocationID.xy;
    if (any(greaterThanEqual(p, pc.dims.xy))) return;
    uint h = hash_u32(p.y * pc.dims.x + p.x);
    vec2 uv = (vec2(p) + 0.5) * pc.scale.xy;
    vec4 sum = vec4(0.0);
    for (uint i = 0u; i < pc.dims.z; i++) {
        vec3 c;
        if (pc.dims.w != 0u) {
            h = h * 1664525u + 1013904223u;
            uint h2 = h * 1664525u + 1013904223u;
            uint h3 = h2 * 1664525u + 1013904223u;
            c = vec3(unit_float(h), unit_float(h2), unit_float(h3));
            h = h3;
        } else {
            c = vec3(uv, (float(i) + 0.5) * pc.scale.z);
        }
        sum += textureLod(sampler3D(tex, smp), c, 0.0);
    }
    result.v[p.y * pc.dims.x + p.x] = sum;
}
