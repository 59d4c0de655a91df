// Environment light shadowed by the character's own sphere tree, per vertex (see
// src/kernels/env/mod.rs for the method; kernels::env::cpu::shadow_vertex is the twin, step
// for step). Per lobe j: the product lobe P_j = G_j x cosine SG; for every sphere of AO's cut
// (the walk of glsl/ao/occlusion.comp: refinement, blend weights, inside fade) above the
// horizon, the fraction O_js of P_j inside the sphere's cap (a table lookup, small caps and
// large alike) times the cap's share above the horizon. The caps' visibility of lobe j is
// C_j = prod_s (1 - O_js)^w_s (log space; with ENV_RAYS a product of 1 - w_s (1 - (1 - O_js)),
// the weighted factor linear in w_s).
// Module env/shadow: V_j = clamp(A(x) C_j / prod_s (1 - I_s)^w_s, 0, 1), I_s AO's per-sphere
// cosine-weighted occlusion and A(x) the visibility bound as `ao` (AO's).
// Module env/shadow_rays (ENV_RAYS): the rays of pass `env trace` correct C_j per lobe,
// V_j = clamp(C_j + sum_k K_jk (e_k - c_k) / sum_k K_jk, 0, 1): e_k whether ray k escaped
// the mesh, c_k the caps' transmission along it (prod over the caps holding it of
// MIN_TRANSMISSION^w_s), K_jk = exp(min(lambda_j, cv_sharpness) (axis_j . d_k - 1)).
// Irradiance = sum_j V_j E_j(n) amplitude_j.
#extension GL_EXT_control_flow_attributes : require
#include <common/util.glsl>
#include <common/ao.glsl>
layout(local_size_x = 64) in;

layout(push_constant) uniform Push {
    uint vertex_count;
    uint lobe_count;
    uint node_count;
    uint first_leaf;
    float tau;
    float band;
    uint refine_extent;
    uint clamp_inside;
    float min_transmission;
#ifdef ENV_RAYS
    uint grid;            // rays per vertex = grid^2 = RAYS
    uint seed;            // pass `env trace`'s seed
    float cv_sharpness;   // the rays' kernel is no sharper than this
#endif
} pc;

layout(std430, set = 0, binding = 0) readonly buffer Positions { vec4 p[]; } pos;
layout(std430, set = 0, binding = 1) readonly buffer Normals { vec4 n[]; } nrm;
// AO's posed tree as `ao skin` writes it (AoKernel::tree_image, glsl/ao/skin.comp): texel 2n
// the sphere, texel 2n + 1 (extent, share = 1 / the node's used children, 0, 0), NODE_ROW
// texels a row. An image: lavapipe loads an image texel with one vector gather, a
// storage-buffer element at a per-lane address with a loop over the lanes (and the share
// was counted here from the B children's radii at every descent).
layout(set = 0, binding = 2, rgba32f) readonly uniform image2D tree;
layout(constant_id = 2) const uint NODE_ROW = 4096u; // kernels::table_row

vec4 tree_texel(uint t) {
    return imageLoad(tree, table_texel(t, NODE_ROW));
}
#ifndef ENV_RAYS
layout(std430, set = 0, binding = 4) readonly buffer Ao { float v[]; } ao;
#else
// Pass `env trace`'s escape bits: ceil(grid^2 / 32) words per vertex.
layout(std430, set = 0, binding = 4) readonly buffer Escaped { uint w[]; } escaped;
#include <env/rays.glsl>
// Rays per vertex (grid^2), a specialization constant so that the per-ray arrays have a
// fixed size and the loops over them a fixed count (lavapipe then keeps them in registers).
layout(constant_id = 0) const uint RAYS = 16u;
#endif
layout(std430, set = 0, binding = 5) readonly buffer Lobes { vec4 l[]; } lobes;
// kernels::env::pack::CapTable::quads: per cell the 2 x 2 corners in (alpha, s), the
// N_S - 1 cells of one (lambda, alpha) a row (an image: lavapipe loads its texel's four
// channels at once, a storage buffer's vec4 at a per-lane index as four gathers).
layout(set = 0, binding = 6, rgba32f) readonly uniform image2D table;
layout(std430, set = 0, binding = 7) writeonly buffer Visibility { float v[]; } vis;
layout(std430, set = 0, binding = 8) writeonly buffer Irradiance { vec4 e[]; } irr;
#include <env/listed.glsl>

// The lobe count (1..=kernels::env::pack::MAX_LOBES; pc.lobe_count is the same), a
// specialization constant so that the loops over the lobes have a fixed count and, marked
// [[unroll]], are unrolled: the per-lobe arrays then live in registers instead of per-lane
// memory, and the lobe's terms taken once per lobe stay there (`bench frame`: `env shadow`
// 8.3-9.2 -> 6.5-6.7 ms with 16 lobes; either change alone saved little or nothing).
layout(constant_id = 1) const uint LOBES = 64u;
// kernels::ao::cpu::{MAX_DEPTH, INSIDE_FADE}.
const uint MAX_DEPTH = 8u;
// The tree's levels below the root (kernels::ao::cpu::TreeShape::levels, at most MAX_DEPTH),
// the deepest the walk's parent state goes: a specialization constant, so that the loops
// over the depths below have a fixed count.
layout(constant_id = 3) const uint LEVELS = MAX_DEPTH;
// The tree's branch factor (kernels::ao::cpu::TreeShape::branch), a specialization constant
// as in glsl/ao/occlusion.comp: the walk's climb divides by it, and a division by a value
// known only at run time is one scalar division per lane (8 a SIMD step on lavapipe), by a
// constant a multiply or, for 8, a shift (`bench env`, fastest of 5 alternated runs: 16
// lobes 8.87 -> 8.14 ms, 8 lobes 7.13 -> 6.40).
layout(constant_id = 4) const uint BRANCH = 8u;
const float INSIDE_FADE = 0.25;
// kernels::env::{COSINE_SHARPNESS, COSINE_AMPLITUDE, HILL_MIN_SHARPNESS}.
const float COS_SHARPNESS = 2.133;
const float COS_AMPLITUDE = 1.17;
const float HILL_MIN_SHARPNESS = 1.0;
// The cap table's axes: kernels::env::pack::{LOG_MIN, LOG_MAX, N_LAMBDA, N_ALPHA, N_S, S_MAX}.
const float LOG_MIN = -4.0;
const float LOG_MAX = 14.0;
const uint N_LAMBDA = 145u;
const uint N_ALPHA = 49u;
const uint N_S = 65u;
const float S_MAX = 8.0;
const float FRAC_2_PI = 0.636619772367581;

// As kernels::ao::cpu::refinement.
float refinement(float size, float d, float tau, float band) {
    if (size <= 0.0) return 0.0;
    float t = tau * d / size;
    if (band > 0.0) return clamp((1.0 + band - t) / band, 0.0, 1.0);
    return t < 1.0 ? 1.0 : 0.0;
}

// The lobe's terms of the cap table's lookup, taken once per lobe
// (kernels::env::pack::CapTable::lookup, the same operations): sqrt(max(lambda, 4)),
// max(lambda, 1) and the lambda axis' row offset.
struct LobeTerms {
    float sq4;
    float l1;
    int row;
};

LobeTerms lobe_terms(float lambda) {
    LobeTerms l;
    l.sq4 = sqrt(max(lambda, 4.0));
    l.l1 = max(lambda, 1.0);
    float x = clamp((log2(lambda) - LOG_MIN) / (LOG_MAX - LOG_MIN), 0.0, 1.0) * float(N_LAMBDA - 1u);
    uint i = min(uint(x + 0.5), N_LAMBDA - 1u);
    l.row = int(i * (N_ALPHA - 1u));
    return l;
}

// kernels::env::pack::acos_fast: acos within 6.7e-5 rad (Abramowitz and Stegun 4.4.45), for
// the table's s axis (a quarter lobe width a cell). lavapipe's acos took 1.3 of `env shadow`'s
// 9.2 ms.
float acos_fast(float x) {
    float a = abs(x);
    float r = sqrt(max(1.0 - a, 0.0)) * (1.5707288 + a * (-0.2121144 + a * (0.0742610 + a * -0.0187293)));
    return x < 0.0 ? AO_PI - r : r;
}

// Fraction of a unit SG (terms lt) inside a cap of half-angle alpha (1 - cos alpha =
// one_minus_cos_a; the alpha axis' cell ja, fraction fy) whose axis is at cos_g from the
// lobe's: kernels::env::pack::cap_occlusion, the table's lookup (CapTable::lookup) at gamma =
// acos_fast(cos_g). The table holds the fraction over m = x / (1 + x), x = (1 - cos alpha)
// max(lambda, 1) (the cap's size against the lobe's), so that a small cap's fraction, ~ x,
// interpolates as well as a large one's: one lookup for caps of every size.
float cap_occlusion(LobeTerms lt, float cos_g, float alpha, float one_minus_cos_a, int ja,
                    float fy) {
    float s = (acos_fast(clamp(cos_g, -1.0, 1.0)) - alpha) * lt.sq4;
    if (s >= S_MAX) return 0.0;
    float z = clamp((s + S_MAX) / (2.0 * S_MAX), 0.0, 1.0) * float(N_S - 1u);
    uint k = min(uint(z), N_S - 2u);
    float fz = z - float(k);
    // One load: the (alpha, s) corners at the nearest lambda sample.
    vec4 q = imageLoad(table, ivec2(k, lt.row + ja));
    float r0 = q.x + (q.y - q.x) * fz;
    float r1 = q.z + (q.w - q.z) * fz;
    float m = one_minus_cos_a * lt.l1;
    return (r0 + (r1 - r0) * fy) * (m / (1.0 + m));
}

// kernels::env::pack::above_horizon.
float above_horizon(float cos_t, float alpha) {
    float x = clamp(asin(clamp(cos_t, -1.0, 1.0)) / max(alpha, 1e-6), -1.0, 1.0);
    return (acos(-x) + x * sqrt(max(1.0 - x * x, 0.0))) / AO_PI;
}

// Irradiance of a unit SG on normal n (no 1/pi): kernels::env::cpu::irradiance.
float sg_irradiance(vec3 p, float lambda, vec3 n) {
    float x = dot(p, n);
    if (lambda < HILL_MIN_SHARPNESS) {
        float lc = COS_SHARPNESS;
        float r = length(p * lambda + n * lc);
        float e = -2.0 * lambda * lc * max(1.0 - x, 0.0) / (r + lambda + lc);
        float tail = r > 1e-6 ? (1.0 - exp(-2.0 * r)) / r : 2.0;
        return 2.0 * AO_PI * COS_AMPLITUDE * exp(e) * tail;
    }
    float c0 = 0.36;
    float c1 = 1.0 / (4.0 * c0);
    float eml = exp(-lambda);
    float em2l = eml * eml;
    float rl = 1.0 / lambda;
    float scale = 1.0 + 2.0 * em2l - rl;
    float bias = (eml - em2l) * rl - em2l;
    float s = sqrt(max(1.0 - scale, 0.0));
    float x0 = c0 * x;
    float x1 = c1 * s;
    float y = abs(x0) <= x1 ? (x0 + x1) * (x0 + x1) / s : clamp(x, 0.0, 1.0);
    return max((scale * y + bias) * 2.0 * AO_PI * rl, 0.0);
}

void main() {
    uint vi;
    if (!listed_vertex(gl_GlobalInvocationID.x, vi)) return;
    vec3 p = pos.p[vi].xyz;
    vec3 n = nrm.n[vi].xyz;

    vec4 prod[LOBES]; // product lobes: axis, sharpness
    // Rays: prod_s (1 - w_s O'_js), O'_js = min(O_js, 1 - min_transmission): the weighted
    // factor linear in w (exact at w = 0 and 1; the blend weights are fractional only across a
    // refinement band), a product with no log per cap and lobe. Without rays:
    // log prod_s (1 - O'_js)^w, which AO's log product u divides exactly.
    float acc[LOBES];
    LobeTerms terms[LOBES];
    [[unroll]] for (uint j = 0u; j < LOBES; ++j) {
        vec4 a = lobes.l[2u * j];
        vec3 r = a.xyz * a.w + n * COS_SHARPNESS;
        float len = length(r);
        prod[j] = vec4(len > 0.0 ? r / len : n, len);
        terms[j] = lobe_terms(len);
#ifdef ENV_RAYS
        acc[j] = 1.0;
#else
        acc[j] = 0.0;
#endif
    }
    float u = 0.0; // log prod_s (1 - I_s)^w
#ifdef ENV_RAYS
    vec3 dirs[RAYS];
    float logc[RAYS]; // log of the caps' transmission along each ray
    {
        vec3 t, bt;
        ray_basis(n, t, bt);
        for (uint k = 0u; k < RAYS; ++k) {
            dirs[k] = ray_direction(vi, k, pc.grid, pc.seed, t, bt, n);
            logc[k] = 0.0;
        }
    }
    float log_floor = log(pc.min_transmission);
#endif
    // The caps the walk finds above the horizon, shaded after it: per cap (axis toward the
    // sphere, sin of its half-angle) and (blend weight, cosine of the sphere's angle to the
    // normal). The walk's steps include the nodes it descends through and the spheres under
    // the horizon; shaded where the walk found each cap, the lobes' loop ran (masked) at every
    // step of the lane with the longest walk (lavapipe runs both sides of an `if`); buffered,
    // it runs once per cap of the lane with the most in each round. The same caps in the same
    // order: the products are the twin's. The buffer is read and written only at constant
    // indices, through unrolled loops over its CAPS slots (a select per slot), so that it
    // lives in registers: indexed by the lane's count it was per-lane memory, stored lane by
    // lane at every walk step and loaded per cap (64 slots then; `bench env`, 16 lobes:
    // 11.4-12.3 -> 8.8-9.3 ms with 8 slots; 4 slots: 10.8-10.9, the rounds' walks wait on
    // each other more; 16: no better than 8). The half-angle (an asin) and the share above
    // the horizon are taken where the cap is shaded: in the walk they ran, masked, at every
    // step.
    const uint CAPS = 8u;
    vec4 cap_axis[CAPS];
    vec2 cap_weight[CAPS];

    // The cut, as glsl/ao/occlusion.comp walks it (kernels::ao::cpu::walk_cut).
    // The parent state of each depth: the effective sphere and (weight, alpha, one child's
    // weight share at alpha = 0). Read and written only at constant indices, through the
    // unrolled loops over the LEVELS depths (a select per depth), so that the arrays live in
    // registers: indexed by the lane's depth they were per-lane memory, each step loading
    // seven channels and the descent storing them lane by lane (`bench env`, 16 lobes:
    // 16.1-16.9 -> 11.6-12.2 ms; `bench frame`, alternated: `env shadow` 9.1-11.3 ->
    // 6.0-6.9 ms).
    vec4 parent_sph[MAX_DEPTH + 1];
    vec3 parent_was[MAX_DEPTH + 1];
    [[unroll]] for (uint i = 0u; i <= LEVELS; ++i) {
        parent_sph[i] = vec4(0.0);
        parent_was[i] = vec3(1.0);
    }
    uint depth = 1u;
    uint node = 1u;
    uint B = BRANCH;
    bool clamp_inside = pc.clamp_inside != 0u;
    // The walk in rounds of at most CAPS caps, each round's caps shaded after it.
    do {
        uint caps = 0u;
        while (node != 0u && node < pc.node_count && caps < CAPS) {
            vec4 s = tree_texel(2u * node);
            vec2 extra = tree_texel(2u * node + 1u).xy;
            bool descend = false;
            if (s.w >= 0.0) {
                vec4 psph = parent_sph[0];
                vec3 pwas = parent_was[0];
                [[unroll]] for (uint i = 1u; i <= LEVELS; ++i) {
                    if (depth == i) {
                        psph = parent_sph[i];
                        pwas = parent_was[i];
                    }
                }
                float a_p = pwas.y;
                vec4 eff = s;
                float w = pwas.x;
                if (a_p < 1.0) {
                    eff = psph + (s - psph) * a_p;
                    w *= pwas.z + (1.0 - pwas.z) * a_p;
                }
                float a = 0.0;
                if (node < pc.first_leaf) {
                    float d = length(s.xyz - p);
                    float size = pc.refine_extent != 0u ? extra.x : s.w;
                    a = min(refinement(size, d, pc.tau, pc.band), a_p);
                }
                if (a > 0.0) {
                    descend = true;
                    depth++;
                    [[unroll]] for (uint i = 1u; i <= LEVELS; ++i) {
                        if (depth == i) {
                            parent_sph[i] = eff;
                            parent_was[i] = vec3(w, a, extra.y);
                        }
                    }
                } else {
                    vec3 dv = eff.xyz - p;
                    float d = length(dv);
                    if (d > eff.w || clamp_inside) {
                        float h = d / eff.w;
                        if (!clamp_inside && h < 1.0 + INSIDE_FADE) h /= max((h - 1.0) / INSIDE_FADE, 1e-6);
                        float cos_t = d > 0.0 ? dot(n, dv) / d : 1.0;
                        // Whether the sphere counts (the exact condition, in both modules);
                        // its occlusion only for AO's product u, which only the module
                        // without rays divides by (with rays the acos, atan and roots of
                        // the occlusion, the old test, ran at every step for nothing:
                        // `bench env`, fastest of 5 alternated runs: 8 lobes 6.40 -> 5.53 ms,
                        // 16 lobes 8.14 -> 7.53).
                        if (sphere_above_horizon(cos_t, h)) {
#ifndef ENV_RAYS
                            float occ = sphere_occlusion(cos_t, h);
                            u += w * log(max(1.0 - occ, pc.min_transmission));
#endif
                            vec3 wc = d > 0.0 ? dv / d : n;
                            float sin_a = min(1.0 / max(h, 1.0), 1.0);
                            [[unroll]] for (uint i = 0u; i < CAPS; ++i) {
                                if (caps == i) {
                                    cap_axis[i] = vec4(wc, sin_a);
                                    cap_weight[i] = vec2(w, cos_t);
                                }
                            }
                            caps++;
                        }
                    }
                }
            }
            if (descend) {
                node = node * B + 1u;
            } else {
                while (node != 0u && (node - 1u) % B == B - 1u) {
                    node = (node - 1u) / B;
                    depth--;
                }
                if (node != 0u) node += 1u;
            }
        }

        for (uint c = 0u; c < caps; ++c) {
            vec4 ca = cap_axis[0];
            vec2 cw = cap_weight[0];
            [[unroll]] for (uint i = 1u; i < CAPS; ++i) {
                if (c == i) {
                    ca = cap_axis[i];
                    cw = cap_weight[i];
                }
            }
            vec3 wc = ca.xyz;
            float sin_a = ca.w;
            float w = cw.x;
            float alpha = asin(sin_a);
            float up = above_horizon(cw.y, alpha);
            float omc = sin_a * sin_a / (1.0 + sqrt(max(1.0 - sin_a * sin_a, 0.0)));
#ifdef ENV_RAYS
            float cos_a = sqrt(max(1.0 - sin_a * sin_a, 0.0));
            for (uint k = 0u; k < RAYS; ++k) {
                if (dot(dirs[k], wc) >= cos_a) logc[k] += w * log_floor;
            }
#endif
            // The cap's terms of the table's lookup (its alpha axis).
            float ya = sqrt(clamp(alpha * FRAC_2_PI, 0.0, 1.0)) * float(N_ALPHA - 1u);
            uint ja = min(uint(ya), N_ALPHA - 2u);
            float fy = ya - float(ja);
            [[unroll]] for (uint j = 0u; j < LOBES; ++j) {
                float o = up * cap_occlusion(terms[j], dot(prod[j].xyz, wc), alpha, omc,
                                             int(ja), fy);
                float f = max(1.0 - o, pc.min_transmission);
#ifdef ENV_RAYS
                acc[j] *= 1.0 - w * (1.0 - f);
#else
                acc[j] += w * log(f);
#endif
            }
        }
    } while (node != 0u && node < pc.node_count);
#ifndef ENV_RAYS
    float a_vis = ao.v[vi];
#else
    // logc becomes the residual e_k - c_k of each ray.
    uint words = (RAYS + 31u) / 32u;
    for (uint k = 0u; k < RAYS; ++k) {
        float esc = float((escaped.w[vi * words + k / 32u] >> (k & 31u)) & 1u);
        logc[k] = esc - exp(logc[k]);
    }
#endif
    vec3 e = vec3(0.0);
    [[unroll]] for (uint j = 0u; j < LOBES; ++j) {
        vec4 a = lobes.l[2u * j];
#ifndef ENV_RAYS
        float vj = clamp(a_vis * exp(acc[j] - u), 0.0, 1.0);
#else
        float lk = min(a.w, pc.cv_sharpness);
        float sk = 0.0;
        float sr = 0.0;
        for (uint k = 0u; k < RAYS; ++k) {
            float kw = exp(lk * (dot(a.xyz, dirs[k]) - 1.0));
            sk += kw;
            sr += kw * logc[k];
        }
        float vj = clamp(acc[j] + sr / max(sk, 1e-30), 0.0, 1.0);
#endif
        vis.v[vi * LOBES + j] = vj;
        e += vj * sg_irradiance(a.xyz, a.w, n) * lobes.l[2u * j + 1u].xyz;
    }
    irr.e[vi] = vec4(e, 0.0);
}
