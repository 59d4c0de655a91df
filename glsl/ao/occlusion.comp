#version 450
#include <common/util.glsl>
// Per-vertex ambient visibility from a cut through a skinned sphere tree.
//
// Cut: preorder walk of the implicit B-ary tree (children of n: n*B+1 .. n*B+B), starting at
// level 1. An inner node is refined when size >= tau * distance, where size is its radius
// (REFINE = 0, the published test) or its extent, the reach of its skinned leaves
// (REFINE = 1: an elongated cluster, an arm, is refined when its leaves come near, not when
// its compact volume sphere does); otherwise it (or a leaf) contributes, so a parent and its
// children never both count. Between size = tau * d and size = tau * d / (1 + band) the node
// blends into its children: they are morphed from its sphere towards their own and weighted
// so that the family equals the node at the far end (src/kernels/ao/cpu.rs, walk_cut): the
// cut changes without popping. A receiver inside a
// sphere either skips it or clamps h to 1 (CLAMP_INSIDE).
//
// Per sphere: the exact formula or a bilinear lookup in the (solid angle, angle) table.
// Blending: product of (1 - I); clamped sum; or the cone-mask union: the analytic sum of I,
// scaled by |union of cone masks| / sum of mask counts over 128 fixed cosine-distributed
// directions (exact for coincident and for disjoint caps); a cap too small to hold a
// direction is left out when its nearest direction is covered already (without that, the
// small caps hidden behind nearer ones added up, and the error grew as the cut refined).
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
layout(constant_id = 5) const uint BRANCH = 8u;         // the tree's branch factor
layout(constant_id = 7) const uint LEVELS = 3u;         // the tree's levels below the root

layout(push_constant) uniform Push {
    uint vertex_count;
    uint node_count;
    uint branch;
    uint first_leaf;
    float tau;
    uint table_n_psi;
    uint table_n_theta;
    float band;
} pc;

layout(std430, set = 0, binding = 0) readonly buffer Positions { vec4 p[]; } pos;
layout(std430, set = 0, binding = 1) readonly buffer Normals { vec4 n[]; } nrm;
// The table as quads (Buffers::table_quads): texel (i, j) holds entries (i, j), (i + 1, j),
// (i, j + 1), (i + 1, j + 1), so a bilinear lookup is one image load.
layout(set = 0, binding = 3, rgba32f) uniform readonly image2D table_quads;
layout(std430, set = 0, binding = 4) readonly buffer Correction { float c[]; } correction;
layout(std430, set = 0, binding = 5) writeonly buffer Visibility { float v[]; } ao;
layout(std430, set = 0, binding = 6) writeonly buffer Stats { uvec2 tested_used[]; } stats;
// Written by `ao skin`, two texels a node (glsl/ao/skin.comp): the posed sphere, then
// (extent, share, 0, 0), share = 1 / the node's used children (a child's weight share at
// alpha = 0, static per tree; loading it beats counting the children in every iteration).
// An image, not storage buffers: on lavapipe an image load is one vector gather, a
// storage-buffer load at a per-lane address a loop over the lanes.
layout(set = 0, binding = 2, rgba32f) uniform readonly image2D nodes;
layout(constant_id = 6) const uint NODE_ROW = 4096u; // kernels::table_row

vec4 node_sphere(uint n) {
    uint t = 2u * n;
    return imageLoad(nodes, table_texel(t, NODE_ROW));
}

// (extent, share) of node n.
vec2 node_extra(uint n) {
    uint t = 2u * n + 1u;
    return imageLoad(nodes, table_texel(t, NODE_ROW)).xy;
}
// formula::nearest_direction_table, four 8-bit direction indices a word.
layout(set = 0, binding = 9, r32ui) uniform readonly uimage2D nearest;  // NODE_ROW words a row
// The vertices along a Morton curve (gpu::spatial_order): neighbouring lanes walk alike cuts.
layout(std430, set = 0, binding = 10) readonly buffer Order { uint i[]; } order;

// Deepest tree walked (levels below the root); cpu::MAX_DEPTH, checked by Prepared::check.
const uint MAX_DEPTH = 8u;
// cpu::INSIDE_FADE.
const float INSIDE_FADE = 0.25;

const uint BLEND_PRODUCT = 0u;
const uint BLEND_SUM = 1u;
const uint BLEND_MASK = 2u;

// How far a node is refined, in [0, 1] (0: itself, 1: its children); as
// kernels::ao::cpu::refinement.
float ao_refinement(float size, float d, float tau, float band) {
    if (size <= 0.0) return 0.0;
    float t = tau * d / size;
    if (band > 0.0) return clamp((1.0 + band - t) / band, 0.0, 1.0);
    return t < 1.0 ? 1.0 : 0.0;
}

float table_lookup(float cos_t, float h) {
    vec2 uv = ao_table_coords(cos_t, h);
    float x = uv.x * float(pc.table_n_psi - 1u);
    float y = uv.y * float(pc.table_n_theta - 1u);
    uint i0 = min(uint(x), pc.table_n_psi - 2u);
    uint j0 = min(uint(y), pc.table_n_theta - 2u);
    float fx = x - float(i0);
    float fy = y - float(j0);
    vec4 q = imageLoad(table_quads, ivec2(int(i0), int(j0)));
    float a = q.x + (q.y - q.x) * fx;
    float b = q.z + (q.w - q.z) * fx;
    return a + (b - a) * fy;
}

// formula::nearest_cell and its table entry: the mask direction nearest wl's cell.
uint nearest_direction(vec3 wl) {
    float last = float(AO_NEAREST_RES - 1u);
    uint ix = uint(clamp((wl.x * 0.5 + 0.5) * float(AO_NEAREST_RES), 0.0, last));
    uint iy = uint(clamp((wl.y * 0.5 + 0.5) * float(AO_NEAREST_RES), 0.0, last));
    uint below = wl.z < 0.0 ? 1u : 0u;
    uint i = (below * AO_NEAREST_RES + iy) * AO_NEAREST_RES + ix;
    uint w = i >> 2u;
    uint word = imageLoad(nearest, table_texel(w, NODE_ROW)).x;
    return (word >> ((i & 3u) * 8u)) & 255u;
}

// The parent state of `node` (at `depth`) as the walk's descent left it: from depth 1 down
// the node's ancestors, each refined as in main (cpu::walk_cut).
void ancestor_state(uint node, uint depth, vec3 p, out vec4 p_sph, out float p_w, out float p_a,
                    out float p_share) {
    p_sph = vec4(0.0);
    p_w = 1.0;
    p_a = 1.0;
    p_share = 1.0;
    uint B = BRANCH;
    // First index of depth `depth` and B^(depth - 1).
    uint first = 1u;
    uint span = 1u;
    for (uint j = 1u; j < depth; ++j) {
        first = first * B + 1u;
        span *= B;
    }
    uint i = node - first;
    uint first_j = 1u;
    for (uint j = 1u; j < depth; ++j) {
        uint n = first_j + i / span;
        vec4 s = node_sphere(n);
        vec2 extra = node_extra(n);
        vec4 eff = s;
        float w = p_w;
        if (p_a < 1.0) {
            eff = p_sph + (s - p_sph) * p_a;
            w *= p_share + (1.0 - p_share) * p_a;
        }
        float d = length(s.xyz - p);
        float size = REFINE == 1u ? extra.x : s.w;
        float a = min(ao_refinement(size, d, pc.tau, pc.band), p_a);
        p_sph = eff;
        p_w = w;
        p_a = a;
        p_share = extra.y;
        first_j = first_j * B + 1u;
        span /= B;
    }
}

void main() {
    if (gl_GlobalInvocationID.x >= pc.vertex_count) return;
    uint vi = order.i[gl_GlobalInvocationID.x];
    vec3 p = pos.p[vi].xyz;
    vec3 n = nrm.n[vi].xyz;
    vec3 t, b;
    ao_basis(n, t, b);

    float product = 1.0;
    float sum_all = 0.0;      // weighted sum of I over all contributing spheres
    float sum_masked = 0.0;   // weighted sum of I over spheres with a non-empty mask
    float count_sum = 0.0;    // weighted sum of mask counts
    uvec4 uni = uvec4(0u);    // union of masks
    uvec4 small = uvec4(0u);  // nearest directions taken by caps too small to hold one
    float hidden = 0.0;       // weighted I of small caps hidden behind others
    uint tested = 0u;
    uint used = 0u;

    // The state of the current depth's parent: its effective sphere, its weight, its alpha
    // and one child's weight share at alpha = 0 (see cpu::walk_cut). Held in registers, not
    // a per-depth stack: a private array indexed by depth is a select ladder or scratch
    // memory on SIMD drivers (lavapipe) and cost ~40% of the pass; after a climb, the state
    // is recomputed from the root down the new node's path (ancestor_state), the same
    // operations the descent made, so the result is bit for bit the same.
    vec4 p_sph = vec4(0.0);
    float p_w = 1.0;
    float p_a = 1.0;
    float p_share = 1.0;
    uint depth = 1u;
    // The parent state of depth 2 (set when a level-1 node is refined): a climb back to
    // depth 1 or 2 restores its state instead of recomputing it. ancestor_state is compiled
    // in only for trees of more than 3 levels: a loop costs lavapipe even when no lane
    // enters it, and its mere presence cost ~20% of the pass (the 8/64/512 tree never
    // needs it).
    vec4 s2_sph = vec4(0.0);
    float s2_w = 1.0;
    float s2_a = 1.0;
    float s2_share = 1.0;

    uint node = 1u;
    uint B = BRANCH;
    while (node != 0u && node < pc.node_count) {
        vec4 s = node_sphere(node);
        vec2 extra = node_extra(node);
        bool descend = false;
        if (s.w >= 0.0) {
            tested++;
            vec4 eff = s;
            float w = p_w;
            if (p_a < 1.0) {
                eff = p_sph + (s - p_sph) * p_a;
                w *= p_share + (1.0 - p_share) * p_a;
            }
            float a = 0.0;
            if (node < pc.first_leaf) {
                float d = length(s.xyz - p);
                float size = REFINE == 1u ? extra.x : s.w;
                a = min(ao_refinement(size, d, pc.tau, pc.band), p_a);
            }
            if (a > 0.0) {
                descend = true;
                depth++;
                p_sph = eff;
                p_w = w;
                p_a = a;
                p_share = extra.y;
                if (depth == 2u) {
                    s2_sph = eff;
                    s2_w = w;
                    s2_a = a;
                    s2_share = extra.y;
                }
            } else {
                vec3 dv = eff.xyz - p;
                float d = length(dv);
                if (d > eff.w || CLAMP_INSIDE) {
                    float h = d / eff.w;
                    // Shrink to nothing over INSIDE_FADE radii outside the sphere (cpu.rs):
                    // skipping it the moment it holds the receiver would pop.
                    if (!CLAMP_INSIDE && h < 1.0 + INSIDE_FADE) h /= max((h - 1.0) / INSIDE_FADE, 1e-6);
                    float cos_t = d > 0.0 ? dot(n, dv) / d : 1.0;
                    float occ = EXACT ? sphere_occlusion(cos_t, h) : table_lookup(cos_t, h);
                    used++;
                    product *= w >= 1.0 ? 1.0 - occ : pow(1.0 - occ, w);
                    sum_all += w * occ;
                    if (BLEND == BLEND_MASK && occ > 0.0) {
                        vec3 wd = d > 0.0 ? dv / d : n;
                        vec3 wl = vec3(dot(wd, t), dot(wd, b), dot(wd, n));
                        float cos_a = sqrt(max(1.0 - 1.0 / max(h * h, 1.0), 0.0));
                        uvec4 m = ao_cap_mask(wl, cos_a);
                        uint c = uint(bitCount(m.x) + bitCount(m.y) + bitCount(m.z) + bitCount(m.w));
                        if (c > 0u) {
                            sum_masked += w * occ;
                            count_sum += w * float(c);
                            uni |= m;
                        } else {
                            // A cap between the directions: hidden when its nearest direction
                            // (looked up by its centre) is covered already (see cpu.rs).
                            uint k = nearest_direction(wl);
                                                        uint bit = 1u << (k & 31u);
                            if (((uni[k >> 5u] | small[k >> 5u]) & bit) == 0u) {
                                small[k >> 5u] |= bit;
                            } else {
                                hidden += w * occ;
                            }
                        }
                    }
                }
            }
        }
        if (descend) {
            node = node * B + 1u;
        } else {
            // Next in preorder: climb while this is the last child, then step to the sibling.
            uint from = depth;
            while (node != 0u && (node - 1u) % B == B - 1u) {
                node = (node - 1u) / B;
                depth--;
            }
            if (node != 0u) {
                node += 1u;
                if (depth < from) {
                    if (depth == 1u) {
                        p_sph = vec4(0.0);
                        p_w = 1.0;
                        p_a = 1.0;
                        p_share = 1.0;
                    } else if (depth == 2u) {
                        p_sph = s2_sph;
                        p_w = s2_w;
                        p_a = s2_a;
                        p_share = s2_share;
                    } else if (LEVELS > 3u) {
                        ancestor_state(node, depth, p, p_sph, p_w, p_a, p_share);
                    }
                }
            }
        }
    }

    float occlusion;
    if (BLEND == BLEND_PRODUCT) {
        occlusion = 1.0 - product;
    } else if (BLEND == BLEND_SUM) {
        occlusion = sum_all;
    } else {
        uint u = uint(bitCount(uni.x) + bitCount(uni.y) + bitCount(uni.z) + bitCount(uni.w));
        float scale = count_sum > 0.0 ? float(u) / count_sum : 1.0;
        occlusion = (sum_all - sum_masked - hidden) + sum_masked * scale;
    }
    float visibility = clamp(1.0 - occlusion, 0.0, 1.0);
    if (CORRECT) visibility = min(visibility * correction.c[vi], 1.0);
    ao.v[vi] = visibility;
    stats.tested_used[vi] = uvec2(tested, used);
}
