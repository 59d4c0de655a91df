#version 450
#extension GL_GOOGLE_include_directive : require
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
layout(local_size_x = 64) in;

layout(push_constant) uniform Push {
    vec4 camera;   // xyz, model units
    vec4 albedo;   // rgb
    uint vertices;
    uint grid;     // N
    uint rv;
    uint rw;
    uint one_table; // 1: one view table for all clusters
} pc;

layout(std430, set = 0, binding = 0) readonly buffer Coeffs { float u[]; } vcoeffs;   // n x r_v
layout(std430, set = 0, binding = 1) readonly buffer Cluster { uint c[]; } cluster;   // n
layout(std430, set = 0, binding = 2) readonly buffer View { float w[]; } view;         // C (or 1) x V x r_w
layout(std430, set = 0, binding = 3) readonly buffer M { vec4 v[]; } m;               // C x r_v x r_w
layout(std430, set = 0, binding = 4) readonly buffer Points { vec4 v[]; } points;
layout(std430, set = 0, binding = 5) readonly buffer Normals { vec4 v[]; } normals;
layout(std430, set = 0, binding = 6) writeonly buffer Radiance { vec4 v[]; } radiance;
layout(std430, set = 0, binding = 7) readonly buffer Order { uint v[]; } order;      // n

const uint MAX_RW = 32u;

#include "view.glsl"

void main() {
    uint v = gl_GlobalInvocationID.x;
    if (v >= pc.vertices) return;
    uint idx[4];
    float wt[4];
    view_taps(points.v[v].xyz, normals.v[v].xyz, pc.camera.xyz, pc.grid, idx, wt);
    uint c = cluster.c[v];
    float uw[MAX_RW];
    uint vbase = pc.one_table != 0u ? 0u : c * pc.grid * pc.grid;
    for (uint k = 0u; k < pc.rw; k++) {
        float sum = 0.0;
        for (uint tap = 0u; tap < 4u; tap++) {
            sum += wt[tap] * view.w[(vbase + idx[tap]) * pc.rw + k];
        }
        uw[k] = sum;
    }
    vec3 sum = vec3(0.0);
    uint mbase = c * pc.rv * pc.rw;
    for (uint i = 0u; i < pc.rv; i++) {
        vec3 row = vec3(0.0);
        for (uint k = 0u; k < pc.rw; k++) {
            row += m.v[mbase + i * pc.rw + k].rgb * uw[k];
        }
        sum += vcoeffs.u[v * pc.rv + i] * row;
    }
    radiance.v[order.v[v]] = vec4(pc.albedo.rgb * sum, 1.0);
}
