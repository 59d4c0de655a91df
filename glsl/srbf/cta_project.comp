#version 450
#include <common/util.glsl>
// CTA, per frame, per cluster c and core row (a, b): M_c[a, b] = sum_i G_c[a, b, i] y_c[i] (RGB),
// the core contracted with the projected lighting of pass `srbf cta light`.
layout(local_size_x = 64) in;

layout(push_constant) uniform Push {
    uint entries;  // clusters x r_v x r_w
    uint rows;     // r_v x r_w
    uint rl;
} pc;

layout(std430, set = 0, binding = 0) readonly buffer Cores { float g[]; } cores;  // C x r_v x r_w x r_l
layout(std430, set = 0, binding = 1) readonly buffer Y { vec4 v[]; } y;           // C x r_l
// C x r_v x r_w texels, CTA_ROW wide (texel e at (e % CTA_ROW, e / CTA_ROW)): what
// `srbf cta shade` reads.
layout(set = 0, binding = 2, rgba32f) uniform writeonly image2D m;
layout(constant_id = 0) const uint CTA_ROW = 4096u; // kernels::table_row

void main() {
    uint e = gl_GlobalInvocationID.x;
    if (e >= pc.entries) return;
    uint c = e / pc.rows;
    vec3 sum = vec3(0.0);
    for (uint i = 0u; i < pc.rl; i++) {
        sum += cores.g[e * pc.rl + i] * y.v[c * pc.rl + i].rgb;
    }
    imageStore(m, table_texel(e, CTA_ROW), vec4(sum, 0.0));
}
