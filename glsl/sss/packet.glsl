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
// Which rays of `live` (bit i: origin o[i], direction d[i], reach tmax[i]) are blocked.
uint blocked_rays(vec3 o[RAY_PACKET], vec3 d[RAY_PACKET], float tmax[RAY_PACKET], uint live) {
    vec3 inv[RAY_PACKET];
    for (uint i = 0u; i < RAY_PACKET; i++) inv[i] = 1.0 / d[i];
    uint blocked = 0u;
    uint ni = 0u;
    uint t = 0u;
    uint tend = 0u;
    uint leaf_meet = 0u;
    for (uint step = 0u; (ni != LINK_END || t < tend) && live != 0u && step < MAX_STEPS; step++) {
        bool tri_step = t < tend;
        uvec4 r0, r1, r2;
        step_texels(tri_step, ni, t, r0, r1, r2);
        if (tri_step) {
            vec3 a = uintBitsToFloat(r0.xyz);
            vec3 e1 = uintBitsToFloat(r1.xyz);
            vec3 e2 = uintBitsToFloat(r2.xyz);
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
            hit &= leaf_meet;
            blocked |= hit;
            live &= ~hit;
            t++;
        } else {
            vec3 lo = uintBitsToFloat(r0.xyz);
            vec3 hi = uintBitsToFloat(r1.xyz);
            uint meet = 0u;
            for (uint i = 0u; i < RAY_PACKET; i++) {
                meet |= slab_meets(lo - o[i], hi - o[i], inv[i], tmax[i]) ? (1u << i) : 0u;
            }
            meet &= live;
            if (node_step(meet != 0u, r0, r1, ni, t, tend)) leaf_meet = meet;
        }
    }
    return blocked;
}
#endif
