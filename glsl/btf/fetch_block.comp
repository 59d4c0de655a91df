#version 450
#extension GL_EXT_samplerless_texture_functions : require
// Fetch-rate probe of the `block` texture for `bench btf`: the sustained rate of texelFetch
// of RGBA32UI blocks from the packed BTF, with a pattern like `btf shade`'s (coherent
// coordinates across neighbouring invocations, a pseudo-random layer per fetch, one call
// site in a loop). Each invocation makes `dims.z` fetches and writes their sum.
layout(local_size_x = 16, local_size_y = 4) in;

layout(push_constant) uniform Push {
    uvec4 dims;  // width, height, fetches per invocation, layers
    vec4 scale;  // xy: texture coordinate (in units of the layer) per pixel
} pc;

layout(set = 0, binding = 0) uniform utexture2DArray tex;
layout(std430, set = 0, binding = 2) writeonly buffer Result { vec4 v[]; } result;

void main() {
    uvec2 p = gl_GlobalInvocationID.xy;
    if (any(greaterThanEqual(p, pc.dims.xy))) return;
    vec2 uv = (vec2(p) + 0.5) * pc.scale.xy;
    ivec2 size = textureSize(tex, 0).xy;
    uint h = (p.x / 8u) * 73856093u ^ (p.y / 8u) * 19349663u;
    uvec4 sum = uvec4(0u);
    for (uint i = 0u; i < pc.dims.z; i++) {
        h = h * 1664525u + 1013904223u;
        int layer = int((h >> 8u) % pc.dims.w);
        ivec2 c = ivec2(fract(uv + float(i) * 0.37) * vec2(size));
        sum += texelFetch(tex, ivec3(c, layer), 0);
    }
    result.v[p.y * pc.dims.x + p.x] = vec4(sum);
}
