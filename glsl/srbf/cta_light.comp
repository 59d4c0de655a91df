#version 450
// CTA, per frame, per cluster c and light rank index i: y_c[i] = sum_k L_c[k, i] c_k (RGB), the
// lighting coefficients (pass `srbf lighting`) projected on the cluster's light factor
// (src/kernels/srbf/cta.rs, `Cta::project` is the CPU twin of this and the next pass).
layout(local_size_x = 64) in;

layout(push_constant) uniform Push {
    uint entries;  // clusters x r_l
    uint rl;
    uint basis;    // K
} pc;

layout(std430, set = 0, binding = 0) readonly buffer Light { float f[]; } light;  // C x K x r_l
const uint MAX_BASIS = 1024u;
layout(std140, set = 0, binding = 1) uniform Coeffs { vec4 v[MAX_BASIS]; } coeffs;
layout(std430, set = 0, binding = 2) writeonly buffer Y { vec4 v[]; } y;            // C x r_l

void main() {
    uint e = gl_GlobalInvocationID.x;
    if (e >= pc.entries) return;
    uint c = e / pc.rl, i = e % pc.rl;
    uint base = c * pc.basis * pc.rl + i;
    vec3 sum = vec3(0.0);
    for (uint k = 0u; k < pc.basis; k++) {
        sum += light.f[base + k * pc.rl] * coeffs.v[k].rgb;
    }
    y.v[e] = vec4(sum, 0.0);
}
