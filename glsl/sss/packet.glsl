// Shadow rays walked through the BVH together (glsl/common/bvh.glsl's stackless traversal),
// RAY_PACKET of them (a constant of the includer, at most 32): a node is fetched once and
// entered when any unblocked ray meets it, a leaf's triangles fetched once and tested against
// each ray that met the leaf. Each ray decides as it would alone (common/bvh.glsl any_hit):
// a child's box lies inside its parent's (the refit makes it so) and the slab test is
// monotone in the box, so a ray that misses a node misses everything under it. Used by
// `sss irradiance rays` (neighbouring texels toward one light) and `sss vertex light` (a
// vertex's rays toward its lights).
#ifndef VKSHADE_SSS_PACKET_GLSL
#define VKSHADE_SSS_PACKET_GLSL
#extension GL_EXT_control_flow_attributes : require
#include <common/bvh_rounds.glsl>
// Which rays of `live` (bit i: origin o[i], direction d[i], reach tmax[i]) are blocked.
// In the rounds of common/bvh_rounds.glsl.
uint blocked_rays(vec3 o[RAY_PACKET], vec3 d[RAY_PACKET], float tmax[RAY_PACKET], uint live) {
    vec3 inv[RAY_PACKET];
    for (uint i = 0u; i < RAY_PACKET; i++) inv[i] = 1.0 / d[i];
    uint blocked = 0u;
    uint ni = 0u;
    uint steps = 0u;
    do {
        uvec3 leaf[ROUND_LEAVES];
        uint found = 0u;
        while (ni != LINK_END && found < ROUND_LEAVES && steps < MAX_STEPS) {
            steps++;
            uvec4 r0 = bvh_texel(2u * ni);
            uvec4 r1 = bvh_texel(2u * ni + 1u);
            vec3 lo = uintBitsToFloat(r0.xyz);
            vec3 hi = uintBitsToFloat(r1.xyz);
            uint meet = 0u;
            for (uint i = 0u; i < RAY_PACKET; i++) {
                meet |= slab_meets(lo - o[i], hi - o[i], inv[i], tmax[i]) ? (1u << i) : 0u;
            }
            round_node(meet & live, r0, r1, ni, leaf, found);
        }
        uint k = 0u;
        uint j = 0u;
        while (k < found && live != 0u) {
            uvec2 tri = round_triangle(leaf, k, j);
            uint t = tri.x;
            vec3 a = uintBitsToFloat(bvh_texel(t).xyz);
            vec3 e1 = uintBitsToFloat(bvh_texel(t + 1u).xyz);
            vec3 e2 = uintBitsToFloat(bvh_texel(t + 2u).xyz);
            uint hit = 0u;
            for (uint i = 0u; i < RAY_PACKET; i++) {
                // common/bvh.glsl hit_t, the same operations.
                vec3 p = cross(d[i], e2);
                float det = dot(e1, p);
                float inv_det = 1.0 / det;
                vec3 s = o[i] - a;
                float u = dot(s, p) * inv_det;
                vec3 q = cross(s, e1);
                float v = dot(d[i], q) * inv_det;
                float th = dot(e2, q) * inv_det;
                bool h = !(abs(det) < 1e-12) && !(u < 0.0 || u > 1.0) && !(v < 0.0 || u + v > 1.0)
                    && th > 0.0 && th <= tmax[i];
                hit |= h ? (1u << i) : 0u;
            }
            hit &= tri.y;
            blocked |= hit;
            live &= ~hit;
        }
    } while (ni != LINK_END && live != 0u && steps < MAX_STEPS);
    return blocked;
}
#endif
