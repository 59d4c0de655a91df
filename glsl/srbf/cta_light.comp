#version 450
#include <common/util.glsl>
// CTA, per frame, per cluster c and quad p of light ranks i = 4p .. 4p + 3:
// y_c[i] = sum_k L_c[k, i] c_k (RGB), the lighting coefficients (pass `srbf lighting`)
// projected on the cluster's light factor (src/kernels/srbf/cta.rs, `Cta::project` is the CPU
// twin of this and the next pass). The light factor and y are images, four light ranks a
// texel (zero past r_l): lavapipe runs a storage-buffer load at a per-lane address as a loop
// over the lanes, an image load as one gather (as in cta_shade.comp).
layout(local_size_x = 64) in;

layout(push_constant) uniform Push {
    uint entries;  // clusters x KL
    uint kl;       // KL = ceil(r_l / 4)
    uint basis;    // K
} pc;

// C x K x KL texels: L_c[k, 4p .. 4p + 3] in texel (c K + k) KL + p.
layout(set = 0, binding = 0, rgba32f) uniform readonly image2D light;
const uint MAX_BASIS = 1024u;
layout(std140, set = 0, binding = 1) uniform Coeffs { vec4 v[MAX_BASIS]; } coeffs;
// C x 3 x KL texels: channel ch of y_c[4p .. 4p + 3] in texel (c 3 + ch) KL + p.
layout(set = 0, binding = 2, rgba32f) uniform writeonly image2D y;
layout(constant_id = 0) const uint CTA_ROW = 4096u; // kernels::table_row

void main() {
    uint e = gl_GlobalInvocationID.x;
    if (e >= pc.entries) return;
    uint c = e / pc.kl, p = e % pc.kl;
    uint base = c * pc.basis * pc.kl + p;
    vec4 r = vec4(0.0), g = vec4(0.0), b = vec4(0.0);
    for (uint k = 0u; k < pc.basis; k++) {
        vec4 l = imageLoad(light, table_texel(base + k * pc.kl, CTA_ROW));
        vec3 ck = coeffs.v[k].rgb;
        r += l * ck.r;
        g += l * ck.g;
        b += l * ck.b;
    }
    uint t = c * 3u * pc.kl + p;
    imageStore(y, table_texel(t, CTA_ROW), r);
    imageStore(y, table_texel(t + pc.kl, CTA_ROW), g);
    imageStore(y, table_texel(t + 2u * pc.kl, CTA_ROW), b);
}
