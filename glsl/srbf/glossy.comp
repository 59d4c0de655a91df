#version 450
#extension GL_GOOGLE_include_directive : require
// Glossy shading (src/kernels/srbf/glossy.rs; `GlossyTransfer::shade` is the CPU twin): per
// vertex, the view's four bilinear taps (view.glsl) and the radiance B = albedo * sum_j
// g_j (T_v[j] . c), T_v[j] the vertex's transfer row j (K floats, rows vertex-major) and c
// the lighting coefficients of pass `srbf lighting` (a uniform buffer read at uniform
// indices). With a view grid (terms = 0) the rows are the N x N view nodes and g the taps'
// weights on their four rows; with the BRDF's factorisation (terms = m) the rows are its m
// terms and g_j = sum_taps w_t G[j_t, j], G the factor table (N^2 x m).
layout(local_size_x = 64) in;

layout(push_constant) uniform Push {
    vec4 camera;   // xyz, model units
    vec4 albedo;   // rgb
    uint vertices;
    uint grid;     // N
    uint basis;    // K
    uint terms;    // m, 0 for a view grid
} pc;

layout(std430, set = 0, binding = 0) readonly buffer Rows { float t[]; } rows;
layout(std430, set = 0, binding = 1) readonly buffer Points { vec4 v[]; } points;
layout(std430, set = 0, binding = 2) readonly buffer Normals { vec4 v[]; } normals;
const uint MAX_BASIS = 1024u;
layout(std140, set = 0, binding = 3) uniform Coeffs { vec4 v[MAX_BASIS]; } coeffs;
layout(std430, set = 0, binding = 4) writeonly buffer Radiance { vec4 v[]; } radiance;
layout(std430, set = 0, binding = 5) readonly buffer Table { float g[]; } table;

#include "view.glsl"

vec3 row_dot(uint base) {
    vec3 r = vec3(0.0);
    for (uint k = 0u; k < pc.basis; k++) {
        r += rows.t[base + k] * coeffs.v[k].rgb;
    }
    return r;
}

void main() {
    uint v = gl_GlobalInvocationID.x;
    if (v >= pc.vertices) return;
    uint idx[4];
    float w[4];
    view_taps(points.v[v].xyz, normals.v[v].xyz, pc.camera.xyz, pc.grid, idx, w);
    vec3 sum = vec3(0.0);
    if (pc.terms == 0u) {
        uint views = pc.grid * pc.grid;
        for (uint tap = 0u; tap < 4u; tap++) {
            sum += w[tap] * row_dot((v * views + idx[tap]) * pc.basis);
        }
    } else {
        for (uint j = 0u; j < pc.terms; j++) {
            float g = 0.0;
            for (uint tap = 0u; tap < 4u; tap++) {
                g += w[tap] * table.g[idx[tap] * pc.terms + j];
            }
            sum += g * row_dot((v * pc.terms + j) * pc.basis);
        }
    }
    radiance.v[v] = vec4(pc.albedo.rgb * sum, 1.0);
}
