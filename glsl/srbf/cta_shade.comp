#version 450
#extension GL_GOOGLE_include_directive : require
#extension GL_EXT_control_flow_attributes : require
#include <common/util.glsl>
// CTA shading per vertex: the view's four bilinear taps (view.glsl) in the N x N grid, the
// interpolated view row u_w = sum_t w_t W[j_t] (r_w) and the radiance
// B = albedo * sum_a u_v[a] sum_b M_c[a, b] u_w[b], M_c from pass `srbf cta project`. With a
// view grid W is the cluster's view factor W_c (one table per cluster); with the BRDF's
// factorisation (one_table = 1) the kernel folds W_c into the cluster's core at setup
// (src/kernels/srbf/cta_gpu.rs), so W is the factor table g_j itself, one table for every
// cluster (r_w = m). Lane i shades the i-th vertex of the kernel's order
// (by cluster, then along a Morton curve: a lane's neighbours read the same cluster's
// tables at nearby nodes); the per-vertex inputs are uploaded in that order and the
// radiance is written to the vertex's own slot, order[i].
// The ranks are specialization constants and every loop over them is unrolled, so the view
// row u_w stays in registers (indexed at run time it was a select ladder per read). The view
// table, M_c and the vertex coefficients are read from images, not storage buffers: lavapipe
// runs a storage-buffer load at a per-lane address as a loop over the lanes with a branch
// per component, an image load as one vector gather (on the bunny at ranks 15,24,32 the
// three CTA passes took 20.7 ms with buffers, 8.4-8.9 ms so; README). The images are CTA_ROW
// texels wide, texel t at (t % CTA_ROW, t / CTA_ROW). The vertex coefficients are half
// precision, eight a texel (rgba32ui, two a component, unpackHalf2x16), so a vertex's
// coefficient loads are ceil(r_v / 8); where its last texel has a free component (r_v % 8
// in 1..=6) that component holds the vertex's cluster id and the cluster buffer is not read
// (PACKED_CLUSTER): a vertex then reads 16 ceil(r_v / 8) bytes, else that and 4 more
// (kernels::srbf::cta::Cta::bytes_per_vertex).
layout(local_size_x = 64) in;

layout(constant_id = 0) const uint RV = 8u;    // vertex rank r_v
layout(constant_id = 1) const uint RW = 24u;   // view rank r_w (<= 32)
const uint KW = (RW + 3u) / 4u;                // view-table texels per node (4 terms each)
const uint KV = (RV + 7u) / 8u;                // coefficient texels per vertex (8 halves each)
layout(constant_id = 2) const uint CTA_ROW = 4096u; // kernels::table_row
// 1: the cluster id is component w of the vertex's last coefficient texel.
layout(constant_id = 3) const uint PACKED_CLUSTER = 0u;

layout(push_constant) uniform Push {
    vec4 camera;   // xyz, model units
    vec4 albedo;   // rgb
    uint vertices;
    uint grid;     // N
    uint one_table; // 1: one view table for all clusters
} pc;

// n x KV texels: coefficients 8q .. 8q + 7 of the i-th vertex in texel i * KV + q, component
// j holding 8q + 2j (low half) and 8q + 2j + 1 (high half); with PACKED_CLUSTER the last
// texel's w is the cluster id.
layout(set = 0, binding = 0, rgba32ui) uniform readonly uimage2D vcoeffs;
layout(std430, set = 0, binding = 1) readonly buffer Cluster { uint c[]; } cluster;   // n
// (C or 1) x V nodes x KW texels: terms 4q .. 4q + 3 of node j in texel j * KW + q.
layout(set = 0, binding = 2, rgba32f) uniform readonly image2D view;
// C x r_v x 3 x KW texels: channel ch of M_c[a, 4q .. 4q + 3] in texel
// ((c r_v + a) 3 + ch) KW + q (pass `srbf cta project`; one channel a texel, so a load is
// a dot product with the view row's quad, and the loads per vertex are 3 r_v KW rather than
// r_v r_w).
layout(set = 0, binding = 3, rgba32f) uniform readonly image2D m;
layout(std430, set = 0, binding = 4) readonly buffer Points { vec4 v[]; } points;
layout(std430, set = 0, binding = 5) readonly buffer Normals { vec4 v[]; } normals;
layout(std430, set = 0, binding = 6) writeonly buffer Radiance { vec4 v[]; } radiance;
layout(std430, set = 0, binding = 7) readonly buffer Order { uint v[]; } order;      // n

#include "view.glsl"

ivec2 cta_texel(uint t) {
    return table_texel(t, CTA_ROW);
}

void main() {
    uint v = gl_GlobalInvocationID.x;
    if (v >= pc.vertices) return;
    uint idx[4];
    float wt[4];
    view_taps(points.v[v].xyz, normals.v[v].xyz, pc.camera.xyz, pc.grid, idx, wt);
    uvec4 uv[KV];
    [[unroll]] for (uint q = 0u; q < KV; q++) uv[q] = imageLoad(vcoeffs, cta_texel(v * KV + q));
    uint c = PACKED_CLUSTER != 0u ? uv[KV - 1u].w : cluster.c[v];
    uint vbase = pc.one_table != 0u ? 0u : c * pc.grid * pc.grid;
    vec4 uw[KW];
    [[unroll]] for (uint q = 0u; q < KW; q++) {
        vec4 sum = vec4(0.0);
        [[unroll]] for (uint tap = 0u; tap < 4u; tap++) {
            sum += wt[tap] * imageLoad(view, cta_texel((vbase + idx[tap]) * KW + q));
        }
        uw[q] = sum;
    }
    vec3 sum = vec3(0.0);
    uint mbase = c * RV * 3u * KW;
    [[unroll]] for (uint i = 0u; i < RV; i++) {
        vec3 row = vec3(0.0);
        [[unroll]] for (uint ch = 0u; ch < 3u; ch++) {
            [[unroll]] for (uint q = 0u; q < KW; q++) {
                row[ch] += dot(imageLoad(m, cta_texel(mbase + (i * 3u + ch) * KW + q)), uw[q]);
            }
        }
        sum += unpackHalf2x16(uv[i / 8u][(i / 2u) % 4u])[i % 2u] * row;
    }
    radiance.v[order.v[v]] = vec4(pc.albedo.rgb * sum, 1.0);
}
