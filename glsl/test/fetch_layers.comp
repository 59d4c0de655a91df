#version 450
#extension GL_EXT_samplerless_texture_functions : require
// Test kernel: every texel of every layer of a 2D array texture, fetched without a sampler,
// so a test reads the device's own decoding of a compressed format:
// out[(layer * h + y) * w + x] = texel (x, y) of layer.
layout(local_size_x = 64) in;

layout(push_constant) uniform Push { uvec4 dims; } pc;  // w, h, layers
layout(set = 0, binding = 0) uniform texture2DArray tex;
layout(std430, set = 0, binding = 1) writeonly buffer Out { vec4 v[]; } out_texels;

void main() {
    uint i = gl_GlobalInvocationID.x;
    uint per_layer = pc.dims.x * pc.dims.y;
    if (i >= per_layer * pc.dims.z) return;
    uint layer = i / per_layer;
    uint t = i - layer * per_layer;
    out_texels.v[i] = texelFetch(tex, ivec3(t % pc.dims.x, t / pc.dims.x, layer), 0);
}
