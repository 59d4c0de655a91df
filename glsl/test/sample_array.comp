#version 450
// Test kernel: samples a 2D array texture through a separate sampler at every texel centre
// of mip `lod` of layer `layer`, writing RGBA to `out_texels` (row-major).
layout(local_size_x = 8, local_size_y = 8) in;

layout(push_constant) uniform Push { uvec2 size; uint layer; float lod; } pc;
layout(set = 0, binding = 0) uniform texture2DArray tex;
layout(set = 0, binding = 1) uniform sampler smp;
layout(std430, set = 0, binding = 2) writeonly buffer Out { vec4 v[]; } out_texels;

void main() {
    uvec2 p = gl_GlobalInvocationID.xy;
    if (any(greaterThanEqual(p, pc.size))) return;
    vec2 uv = (vec2(p) + 0.5) / vec2(pc.size);
    out_texels.v[p.y * pc.size.x + p.x] =
        textureLod(sampler2DArray(tex, smp), vec3(uv, float(pc.layer)), pc.lod);
}
