#version 450
// Fetch-rate probe for `bench btf`: the sustained rate of filtered fetches from the packed
// BTF array texture with the same sampler and a similar pattern as `btf shade` (coherent uv
// across neighbouring invocations, a pseudo-random layer per fetch, one call site in a
// loop). Each invocation makes `dims.z` fetches and writes their sum.
layout(local_size_x = 8, local_size_y = 8) in;

layout(push_constant) uniform Push {
    uvec4 dims;  // width, height, fetches per invocation, layers
    vec4 scale;  // xy: uv per pixel
} pc;

layout(set = 0, binding = 0) uniform texture2DArray tex;
layout(set = 0, binding = 1) uniform sampler smp;
layout(std430, set = 0, binding = 2) writeonly buffer Result { vec4 v[]; } result;

void main() {
    uvec2 p = gl_GlobalInvocationID.xy;
    if (any(greaterThanEqual(p, pc.dims.xy))) return;
    vec2 uv = (vec2(p) + 0.5) * pc.scale.xy;
    uint h = (p.x / 8u) * 73856093u ^ (p.y / 8u) * 19349663u;
    vec3 sum = vec3(0.0);
    for (uint i = 0u; i < pc.dims.z; i++) {
        h = h * 1664525u + 1013904223u;
        float layer = float((h >> 8u) % pc.dims.w);
        sum += textureLod(sampler2DArray(tex, smp), vec3(uv + float(i) * 0.37, layer), 0.0).rgb;
    }
    result.v[p.y * pc.dims.x + p.x] = vec4(sum, 1.0);
}
