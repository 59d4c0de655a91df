#version 450
// Per-vertex ambient visibility from a cut through a skinned sphere tree.
//
// Cut: preorder walk of the implicit B-ary tree (children of n: n*B+1 .. n*B+B), starting at
// level 1. An inner node is refined when size > tau * distance, where size is its radius
// (REFINE = 0, the published test) or its extent, the reach of its skinned leaves
// (REFINE = 1: an elongated cluster, an arm, is refined when its leaves come near, not when
// its compact volume sphere does); otherwise it (or a leaf) contributes, so a parent and its
// children never both count. A receiver inside a leaf
// sphere either skips it or clamps h to 1 (CLAMP_INSIDE).
//
// Per sphere: the exact formula or a bilinear lookup in the (solid angle, angle) table.
// Blending: product of (1 - I); clamped sum; or the cone-mask union: the analytic sum of I,
// scaled by |union of cone masks| / sum of mask counts over 128 fixed cosine-distributed
// directions (exact for coincident and for disjoint caps).
//
// Optional static correction: visibility times a per-vertex factor baked in the bind pose
// (ray-traced mesh visibility / this method's visibility, capped), which restores detail no
// sphere set represents (buried or thin geometry); see src/kernels/ao/mod.rs.
#include <common/ao.glsl>
#include <common/ao_mask.glsl>
layout(local_size_x = 64) in;

// Modes are specialization constants, so each pipeline holds only its own code: drivers
// that run both sides of a branch under lane masks (lavapipe) would otherwise pay for the
// mask blend in every mode.
layout(constant_id = 0) const bool EXACT = false;       // closed form instead of the table
layout(constant_id = 1) const uint BLEND = 2u;          // 0 product, 1 sum, 2 cone-mask union
layout(constant_id = 2) const bool CLAMP_INSIDE = false; // receiver inside a leaf: clamp h to 1
layout(constant_id = 3) const bool CORRECT = true;      // apply the static correction
layout(constant_id = 4) const uint REFINE = 1u;         // 0 radius, 1 extent

layout(push_constant) uniform Push {
    uint vertex_count;
    uint node_count;
    uint branch;
    uint first_leaf;
    float tau;
    uint table_n_psi;
    uint table_n_theta;
} pc;

layout(std430, set = 0, binding = 0) readonly buffer Positions { vec4 p[]; } pos;
layout(std430, set = 0, binding = 1) readonly buffer Normals { vec4 n[]; } nrm;
layout(std430, set = 0, binding = 2) readonly buffer Spheres { vec4 s[]; } sph;
layout(std430, set = 0, binding = 3) readonly buffer Table { float v[]; } table;
layout(std430, set = 0, binding = 4) readonly buffer Correction { float c[]; } correction;
layout(std430, set = 0, binding = 5) writeonly buffer Visibility { float v[]; } ao;
layout(std430, set = 0, binding = 6) writeonly buffer Stats { uvec2 tested_used[]; } stats;
layout(std430, set = 0, binding = 7) readonly buffer Extents { float e[]; } ext;

const uint BLEND_PRODUCT = 0u;
const uint BLEND_SUM = 1u;
const uint BLEND_MASK = 2u;

float table_lookup(float cos_t, float h) {
    vec2 uv = ao_table_coords(cos_t, h);
    float x = uv.x * float(pc.table_n_psi - 1u);
    float y = uv.y * float(pc.table_n_theta - 1u);
    uint i0 = min(uint(x), pc.table_n_psi - 2u);
    uint j0 = min(uint(y), pc.table_n_theta - 2u);
    float fx = x - float(i0);
    float fy = y - float(j0);
    uint r0 = j0 * pc.table_n_psi + i0;
    uint r1 = r0 + pc.table_n_psi;
    float a = table.v[r0] + (table.v[r0 + 1u] - table.v[r0]) * fx;
    float b = table.v[r1] + (table.v[r1 + 1u] - table.v[r1]) * fx;
    return a + (b - a) * fy;
}

void main() {
    uint vi = gl_GlobalInvocationID.x;
    if (vi >= pc.vertex_count) return;
    vec3 p = pos.p[vi].xyz;
    vec3 n = nrm.n[vi].xyz;
    vec3 t, b;
    ao_basis(n, t, b);

    float product = 1.0;
    float sum_all = 0.0;      // sum of I over all contributing spheres
    float sum_masked = 0.0;   // sum of I over spheres with a non-empty mask
    uint count_sum = 0u;      // sum of mask counts
    uvec4 uni = uvec4(0u);    // union of masks
    uint tested = 0u;
    uint used = 0u;

    uint node = 1u;
    uint B = pc.branch;
    while (node != 0u && node < pc.node_count) {
        vec4 s = sph.s[node];
        bool descend = false;
        if (s.w >= 0.0) {
            tested++;
            vec3 dv = s.xyz - p;
            float d = length(dv);
            bool leaf = node >= pc.first_leaf;
            float size = REFINE == 1u ? ext.e[node] : s.w;
            if (!leaf && size > pc.tau * d) {
                descend = true;
            } else if (d > s.w || CLAMP_INSIDE) {
                float h = d / s.w;
                float cos_t = d > 0.0 ? dot(n, dv) / d : 1.0;
                float occ = EXACT ? sphere_occlusion(cos_t, h) : table_lookup(cos_t, h);
                used++;
                product *= 1.0 - occ;
                sum_all += occ;
                if (BLEND == BLEND_MASK && occ > 0.0) {
                    vec3 w = d > 0.0 ? dv / d : n;
                    vec3 wl = vec3(dot(w, t), dot(w, b), dot(w, n));
                    float cos_a = sqrt(max(1.0 - 1.0 / max(h * h, 1.0), 0.0));
                    uvec4 m = ao_cap_mask(wl, cos_a);
                    uint c = uint(bitCount(m.x) + bitCount(m.y) + bitCount(m.z) + bitCount(m.w));
                    if (c > 0u) {
                        sum_masked += occ;
                        count_sum += c;
                        uni |= m;
                    }
                }
            }
        }
        if (descend) {
            node = node * B + 1u;
        } else {
            // Next in preorder: climb while this is the last child, then step to the sibling.
            while (node != 0u && (node - 1u) % B == B - 1u) node = (node - 1u) / B;
            if (node != 0u) node += 1u;
        }
    }

    float occlusion;
    if (BLEND == BLEND_PRODUCT) {
        occlusion = 1.0 - product;
    } else if (BLEND == BLEND_SUM) {
        occlusion = sum_all;
    } else {
        uint u = uint(bitCount(uni.x) + bitCount(uni.y) + bitCount(uni.z) + bitCount(uni.w));
        float scale = count_sum > 0u ? float(u) / float(count_sum) : 1.0;
        occlusion = (sum_all - sum_masked) + sum_masked * scale;
    }
    float visibility = clamp(1.0 - occlusion, 0.0, 1.0);
    if (CORRECT) visibility = min(visibility * correction.c[vi], 1.0);
    ao.v[vi] = visibility;
    stats.tested_used[vi] = uvec2(tested, used);
}
