#version 450
#extension GL_GOOGLE_include_directive : require
#extension GL_EXT_control_flow_attributes : require
#include <common/util.glsl>
// CTA, per frame, per cluster c, vertex rank a and quad q of view ranks b = 4q .. 4q + 3:
// M_c[a, b] = sum_i G_c[a, b, i] y_c[i] (RGB), the core contracted with the projected
// lighting of pass `srbf cta light`, stored one channel a texel (the four b of the quad),
// so that `srbf cta shade` takes a dot product per load. The core and y are images, four
// light ranks a texel (zero past r_l), read with one gather each.
layout(local_size_x = 64) in;

layout(push_constant) uniform Push {
    uint entries;  // clusters x r_v x KW
    uint kw;       // KW = ceil(r_w / 4)
    uint rv;
    uint kl;       // KL = ceil(r_l / 4)
} pc;

// C x r_v x 4 KW x KL texels: G_c[a, b, 4p .. 4p + 3] in texel ((c r_v + a) 4 KW + b) KL + p,
// zero for b past r_w (so every quad has four rows).
layout(set = 0, binding = 0, rgba32f) uniform readonly image2D cores;
// C x 3 x KL texels (pass `srbf cta light`).
layout(set = 0, binding = 1, rgba32f) uniform readonly image2D y;
// C x r_v x 3 x KW texels: channel ch of M_c[a, 4q .. 4q + 3] in texel ((c r_v + a) 3 + ch)
// KW + q, zero past r_w; what `srbf cta shade` reads.
layout(set = 0, binding = 2, rgba32f) uniform writeonly image2D m;
layout(constant_id = 0) const uint CTA_ROW = 4096u; // kernels::table_row

void main() {
    uint e = gl_GlobalInvocationID.x;
    if (e >= pc.entries) return;
    uint row = e / pc.kw, q = e % pc.kw;   // row = c r_v + a
    uint c = row / pc.rv;
    vec4 sum[3] = vec4[3](vec4(0.0), vec4(0.0), vec4(0.0)); // channel, then b = 4q + j
    uint g0 = (row * 4u * pc.kw + 4u * q) * pc.kl;
    for (uint p = 0u; p < pc.kl; p++) {
        uint yt = c * 3u * pc.kl + p;
        vec4 yc[3];
        [[unroll]] for (uint ch = 0u; ch < 3u; ch++) {
            yc[ch] = imageLoad(y, table_texel(yt + ch * pc.kl, CTA_ROW));
        }
        [[unroll]] for (uint j = 0u; j < 4u; j++) {
            vec4 g = imageLoad(cores, table_texel(g0 + j * pc.kl + p, CTA_ROW));
            [[unroll]] for (uint ch = 0u; ch < 3u; ch++) sum[ch][j] += dot(g, yc[ch]);
        }
    }
    uint t = row * 3u * pc.kw + q;
    imageStore(m, table_texel(t, CTA_ROW), sum[0]);
    imageStore(m, table_texel(t + pc.kw, CTA_ROW), sum[1]);
    imageStore(m, table_texel(t + 2u * pc.kw, CTA_ROW), sum[2]);
}
