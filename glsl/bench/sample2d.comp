#version 450
// Sampling-rate probe for `bench peak`: `dims.z` textureLod calls per invocation from a 2D
// texture through the bound sampler (nearest or bilinear: the sampler decides; the format is
// the image's). Coherent (dims.w = 0): neighbouring invocations read neighbouring texels and
// each call moves the whole grid one texel right. Random (dims.w = 1): every call at a
// hashed coordinate anywhere in the texture. One store of the sum keeps the calls live.
#include <common/util.glsl>
layout(local_size_x = 16, local_size_y = 16) in;

layout(push_constant) uniform Push {
    uvec4 dims;  // grid width, grid height, calls per invocation, random
    vec4 scale;  // xy: one texel in uv; zw: unused
} pc;

layout(set = 0, binding = 0) uniform texture2D tex;
layout(set = 0, binding = 1) uniform sampler smp;
layout(std430, set = 0, binding = 2) writeonly buffer Result { vec4 v[]; } result;

void main() {
    uvec2 p = gl_GlobalInvocationID.xy;
    if (any(greaterThanEqual(p, pc.dims.xy))) return;
    uint h = hash_u32(p.y * pc.dims.x + p.x);
    vec2 uv = (vec2(p) + 0.5) * pc.scale.xy;
    vec4 sum = vec4(0.0);
    for (uint i = 0u; i < pc.dims.z; i++) {
        vec2 c;
        if (pc.dims.w != 0u) {
            h = h * 1664525u + 1013904223u;
            uint h2 = h * 1664525u + 1013904223u;
            c = vec2(unit_float(h), unit_float(h2));
            h = h2;
        } else {
            c = uv + vec2(float(i) * pc.scale.x, 0.0);
        }
        sum += textureLod(sampler2D(tex, smp), c, 0.0);
    }
    result.v[p.y * pc.dims.x + p.x] = sum;
}
