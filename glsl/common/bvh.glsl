#include <common/util.glsl>
// The stackless BVH traversal shared by the kernels that cast rays on the GPU (SSS: pass
// `sss vertex light` and the texel refinement of `sss irradiance`; SRBF: the compact lobes'
// shadow rays of `srbf sharp`). The same traversal and two-sided Moller-Trumbore test as
// src/geom/bvh.rs (its CPU twin); the table layout is src/geom/bvh.rs `Bvh::flat` with
// `with_links` in place of the counts.
// The includer declares `const uint BVH_ROW` and the table, an image BVH_ROW texels a row
// (lavapipe fetches a texel's four channels at once): the nodes from texel 0, 2 texels each
// (lo xyz, first; hi xyz, link word), then the triangles from texel TRI_BASE, 3 each (a, e1,
// e2), float bits. TRI_BASE is a specialization constant of every pipeline that includes
// this (src/geom/bvh.rs `tri_base`, `table_texels`):
//   layout(rgba32ui) readonly uniform uimage2D nodes;
// One table rather than one image of nodes and one of triangles: a step of the single-ray
// walks below is either kind, the lanes of a SIMD step run both kinds masked (lavapipe), and
// reading three texels at one address per lane costs 3 loads where a node's and a
// triangle's cost 2 + 3. (The packet walks, env/trace.glsl and sss/packet.glsl, take node
// steps and triangle steps in separate loops: 2 texels a node, 3 a triangle.)
// Measured on lavapipe (`bench frame`, alternated runs): `env trace` 5.5-5.9 -> 4.7-4.8 ms.
#include <common/bvh_table.glsl>

// Texel k of the table.
uvec4 bvh_texel(uint k) {
    return imageLoad(nodes, table_texel(k, BVH_ROW));
}

// Row k of the triangles (row 3 t: triangle t's a, + 1 its e1, + 2 its e2).
vec3 tri_row(uint k) {
    return uintBitsToFloat(bvh_texel(TRI_BASE + k).xyz);
}

// The texels of a traversal step: triangle t's three rows when `tri_step`, else node ni's
// two (r0: lo, first; r1: hi, link word) and the texel after them (unused).
void step_texels(bool tri_step, uint ni, uint t, out uvec4 r0, out uvec4 r1, out uvec4 r2) {
    uint k = tri_step ? TRI_BASE + 3u * t : 2u * ni;
    r0 = bvh_texel(k);
    r1 = bvh_texel(k + 1u);
    r2 = bvh_texel(k + 2u);
}

// A node step's move, given its texels r0, r1 (step_texels) and whether a ray that counts
// meets its box: into a leaf's triangles [first, first + count) (returns true), down to an
// inner node's left child, or past the node to its skip.
bool node_step(bool meets, uvec4 r0, uvec4 r1, inout uint ni, inout uint t, inout uint tend) {
    uint first = r0.w;
    uint count = r1.w & 0xffu;
    bool leaf = meets && count != 0u;
    if (leaf) {
        t = first;
        tend = first + count;
    }
    ni = (meets && count == 0u) ? first : r1.w >> 8u;
    return leaf;
}

// Parameter of the hit of the triangle (a, a + e1, a + e2) in (0, tmax], or -1.
float hit_t(vec3 o, vec3 d, vec3 a, vec3 e1, vec3 e2, float tmax) {
    vec3 p = cross(d, e2);
    float det = dot(e1, p);
    if (abs(det) < 1e-12) return -1.0;
    float inv = 1.0 / det;
    vec3 s = o - a;
    float u = dot(s, p) * inv;
    if (u < 0.0 || u > 1.0) return -1.0;
    vec3 q = cross(s, e1);
    float v = dot(d, q) * inv;
    if (v < 0.0 || u + v > 1.0) return -1.0;
    float t_hit = dot(e2, q) * inv;
    return (t_hit > 0.0 && t_hit <= tmax) ? t_hit : -1.0;
}

// Whether the ray o + t d, t in [0, tmax], meets the box [lo, hi], given lo - o, hi - o and
// 1 / d (the slab test every traversal here uses).
bool slab_meets(vec3 lo_o, vec3 hi_o, vec3 inv, float tmax) {
    vec3 t0 = lo_o * inv;
    vec3 t1 = hi_o * inv;
    vec3 tmin = min(t0, t1);
    vec3 tmx = max(t0, t1);
    float tnear = max(max(max(tmin.x, tmin.y), tmin.z), 0.0);
    float tfar = min(min(min(tmx.x, tmx.y), tmx.z), tmax);
    return !(tnear > tfar);
}

// Stackless traversal (src/kernels/sss/posed.rs link_words): a node's hi.w is its
// triangle count | its skip << 8, the node visited next when the ray does not enter it;
// entering an inner node goes to its left child, a leaf's triangles are tested and then its
// skip is taken. The root's skip (0xffffff) ends it; every node step moves forward in the
// depth-first order (MAX_STEPS, which counts node and triangle steps here and node steps in
// the packet walks, each of whose node steps brings at most 255 triangle steps, only guards a
// malformed table).
// One loop whose step is either a node or one triangle of the leaf just entered, not a loop
// over the leaf's triangles inside the node loop: the lanes of a SIMD step walk different
// paths, and a nested loop ran, at every node step, as many triangle steps as the lane with
// the most (every lane waiting, masked, while one tested a leaf). Measured on lavapipe
// (`bench frame`, alternated runs): `env trace` 7.3-7.7 -> 6.2-6.4 ms, `sss irradiance
// rays` 3.2-3.3 -> 2.8 ms, `sss vertex light` 0.84-0.98 -> 0.68-0.71 ms. The packet walks
// (env/trace.glsl, sss/packet.glsl) go further: a step of either kind still pays both, so
// they walk nodes only until a few leaves are met and then test those leaves' triangles.
const uint LINK_END = 0xffffffu;
const uint MAX_STEPS = 1u << 22u;

bool any_hit(vec3 o, vec3 d, float tmax) {
    vec3 inv = 1.0 / d;
    uint ni = 0u;
    uint t = 0u;
    uint tend = 0u;
    for (uint step = 0u; (ni != LINK_END || t < tend) && step < MAX_STEPS; step++) {
        bool tri_step = t < tend;
        uvec4 r0, r1, r2;
        step_texels(tri_step, ni, t, r0, r1, r2);
        if (tri_step) {
            vec3 a = uintBitsToFloat(r0.xyz);
            if (hit_t(o, d, a, uintBitsToFloat(r1.xyz), uintBitsToFloat(r2.xyz), tmax) >= 0.0) {
                return true;
            }
            t++;
        } else {
            vec3 lo = uintBitsToFloat(r0.xyz);
            vec3 hi = uintBitsToFloat(r1.xyz);
            node_step(slab_meets(lo - o, hi - o, inv, tmax), r0, r1, ni, t, tend);
        }
    }
    return false;
}

// Nearest hit in (0, tmax]: (t, triangle), or t < 0. The stackless traversal of any_hit,
// the far bound shrinking to the best hit so far.
vec2 closest_hit(vec3 o, vec3 d, float tmax) {
    vec3 inv = 1.0 / d;
    float best = -1.0;
    uint best_tri = 0u;
    uint ni = 0u;
    uint t = 0u;
    uint tend = 0u;
    for (uint step = 0u; (ni != LINK_END || t < tend) && step < MAX_STEPS; step++) {
        bool tri_step = t < tend;
        uvec4 r0, r1, r2;
        step_texels(tri_step, ni, t, r0, r1, r2);
        if (tri_step) {
            vec3 a = uintBitsToFloat(r0.xyz);
            float th = hit_t(o, d, a, uintBitsToFloat(r1.xyz), uintBitsToFloat(r2.xyz), tmax);
            if (th >= 0.0 && (best < 0.0 || th < best)) {
                best = th;
                best_tri = t;
            }
            t++;
        } else {
            vec3 lo = uintBitsToFloat(r0.xyz);
            vec3 hi = uintBitsToFloat(r1.xyz);
            bool meets = slab_meets(lo - o, hi - o, inv, best >= 0.0 ? best : tmax);
            node_step(meets, r0, r1, ni, t, tend);
        }
    }
    return vec2(best, uintBitsToFloat(best_tri));
}
