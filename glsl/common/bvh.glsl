#include <common/util.glsl>
// The stackless BVH traversal shared by the kernels that cast rays on the GPU (SSS: pass
// `sss vertex light` and the texel refinement of `sss irradiance`; SRBF: the compact lobes'
// shadow rays of `srbf sharp`). The same traversal and two-sided Moller-Trumbore test as
// src/geom/bvh.rs (its CPU twin); the table layout is src/geom/bvh.rs `Bvh::flat` with
// `with_links` in place of the counts.
// The includer declares `const uint BVH_ROW` and the images, row BVH_ROW texels wide (lavapipe
// fetches a texel's four channels at once): nodes 2 texels each (lo xyz, first; hi xyz, link
// word), triangles 3 (a, e1, e2), float bits:
//   layout(rgba32ui) readonly uniform uimage2D nodes;
//   layout(rgba32ui) readonly uniform uimage2D tris;

uvec4 bvh_node(uint k) {
    return imageLoad(nodes, table_texel(k, BVH_ROW));
}

// With BVH_TRI_BASE defined, one table: the triangles' rows follow the nodes in `nodes`,
// from texel BVH_TRI_BASE (no `tris` image).
vec3 tri_row(uint k) {
#ifdef BVH_TRI_BASE
    return uintBitsToFloat(imageLoad(nodes, table_texel(BVH_TRI_BASE + k, BVH_ROW)).xyz);
#else
    return uintBitsToFloat(imageLoad(tris, table_texel(k, BVH_ROW)).xyz);
#endif
}

// Parameter of the hit of triangle t in (0, tmax], or -1.
float hit_t(vec3 o, vec3 d, uint t, float tmax) {
    vec3 a = tri_row(3u * t);
    vec3 e1 = tri_row(3u * t + 1u);
    vec3 e2 = tri_row(3u * t + 2u);
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

bool hit_tri(vec3 o, vec3 d, uint t, float tmax) {
    vec3 a = tri_row(3u * t);
    vec3 e1 = tri_row(3u * t + 1u);
    vec3 e2 = tri_row(3u * t + 2u);
    vec3 p = cross(d, e2);
    float det = dot(e1, p);
    if (abs(det) < 1e-12) return false;
    float inv = 1.0 / det;
    vec3 s = o - a;
    float u = dot(s, p) * inv;
    if (u < 0.0 || u > 1.0) return false;
    vec3 q = cross(s, e1);
    float v = dot(d, q) * inv;
    if (v < 0.0 || u + v > 1.0) return false;
    float t_hit = dot(e2, q) * inv;
    return t_hit > 0.0 && t_hit <= tmax;
}

// Stackless traversal (src/kernels/sss/posed.rs link_words): a node's hi.w is its
// triangle count | its skip << 8, the node visited next when the ray does not enter it;
// entering an inner node goes to its left child, a leaf's triangles are tested and then its
// skip is taken. The root's skip (0xffffff) ends it; every node step moves forward in the
// depth-first order (MAX_STEPS, which counts node and triangle steps, only guards a malformed
// table).
// One loop whose step is either a node or one triangle of the leaf just entered, not a loop
// over the leaf's triangles inside the node loop: the lanes of a SIMD step walk different
// paths, and a nested loop ran, at every node step, as many triangle steps as the lane with
// the most (every lane waiting, masked, while one tested a leaf). Measured on lavapipe
// (`bench frame`, alternated runs): `env trace` 7.3-7.7 -> 6.2-6.4 ms, `sss irradiance
// rays` 3.2-3.3 -> 2.8 ms, `sss vertex light` 0.84-0.98 -> 0.68-0.71 ms (the same shape in
// env/trace.glsl and sss/packet.glsl).
const uint LINK_END = 0xffffffu;
const uint MAX_STEPS = 1u << 22u;

bool any_hit(vec3 o, vec3 d, float tmax) {
    vec3 inv = 1.0 / d;
    uint ni = 0u;
    uint t = 0u;
    uint tend = 0u;
    for (uint step = 0u; (ni != LINK_END || t < tend) && step < MAX_STEPS; step++) {
        if (t < tend) {
            if (hit_tri(o, d, t, tmax)) return true;
            t++;
        } else {
            uvec4 lo_u = bvh_node(2u * ni);
            uvec4 hi_u = bvh_node(2u * ni + 1u);
            vec3 lo = uintBitsToFloat(lo_u.xyz);
            vec3 hi = uintBitsToFloat(hi_u.xyz);
            bool meets = slab_meets(lo - o, hi - o, inv, tmax);
            uint first = lo_u.w;
            uint count = hi_u.w & 0xffu;
            if (meets && count != 0u) {
                t = first;
                tend = first + count;
            }
            ni = (meets && count == 0u) ? first : hi_u.w >> 8u;
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
        if (t < tend) {
            float th = hit_t(o, d, t, tmax);
            if (th >= 0.0 && (best < 0.0 || th < best)) {
                best = th;
                best_tri = t;
            }
            t++;
        } else {
            uvec4 lo_u = bvh_node(2u * ni);
            uvec4 hi_u = bvh_node(2u * ni + 1u);
            vec3 lo = uintBitsToFloat(lo_u.xyz);
            vec3 hi = uintBitsToFloat(hi_u.xyz);
            bool meets = slab_meets(lo - o, hi - o, inv, best >= 0.0 ? best : tmax);
            uint first = lo_u.w;
            uint count = hi_u.w & 0xffu;
            if (meets && count != 0u) {
                t = first;
                tend = first + count;
            }
            ni = (meets && count == 0u) ? first : hi_u.w >> 8u;
        }
    }
    return vec2(best, uintBitsToFloat(best_tri));
}
