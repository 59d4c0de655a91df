#version 450
#extension GL_EXT_samplerless_texture_functions : require
// Test kernel: a descriptor array of three textures; out[i * n + j] = texel j (of a row of
// n texels) of texture i, fetched without a sampler.
layout(local_size_x = 64) in;

layout(push_constant) uniform Push { uint n; } pc;
layout(set = 0, binding = 0) uniform texture2D texs[3];
layout(std430, set = 0, binding = 1) writeonly buffer Out { vec4 v[]; } out_texels;

void main() {
    uint j = gl_GlobalInvocationID.x;
    if (j >= pc.n) return;
    for (int i = 0; i < 3; i++) {
        out_texels.v[uint(i) * pc.n + j] = texelFetch(texs[i], ivec2(j, 0), 0);
    }
}
