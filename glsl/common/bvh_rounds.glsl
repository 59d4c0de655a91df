// The rounds of the packet walks (env/trace.glsl escaping, sss/packet.glsl blocked_rays):
// nodes only until ROUND_LEAVES leaves are met (or the walk ends), then those leaves'
// triangles against the rays that met each, then on from where the walk stopped. A SIMD
// step's lanes run both sides of a branch (lavapipe), so a loop whose step is a node or a
// triangle paid both at every step; a round's node step pays a node's two texels and slab
// tests, its triangle step a triangle's three texels and ray tests. A ray blocked in a
// round's first leaf still walks to the round's end; each ray's answer is the same (it is
// blocked when a triangle of a leaf it meets blocks it). Measured on lavapipe (`bench
// frame`, alternated runs): `env trace` 4.7-5.3 -> 4.4-4.9 ms, `sss irradiance rays`
// 2.3-3.6 -> 2.05-2.15; 2 leaves a round no better, 8 worse (the lanes wait longer on
// each other's rounds). The includer has common/bvh.glsl and
// GL_EXT_control_flow_attributes.
#ifndef VKSHADE_BVH_ROUNDS_GLSL
#define VKSHADE_BVH_ROUNDS_GLSL
const uint ROUND_LEAVES = 4u;

// A round's node step (texels r0, r1; `meet` the live rays that meet its box): common/bvh.glsl
// node_step's move, and a leaf met goes into slot `found` as (first triangle, triangle
// count, meet). The slots are read and written at constant indices only (a select per slot),
// so that they stay in registers.
void round_node(uint meet, uvec4 r0, uvec4 r1, inout uint ni, inout uvec3 leaf[ROUND_LEAVES],
                inout uint found) {
    uint t = 0u;
    uint tend = 0u;
    if (node_step(meet != 0u, r0, r1, ni, t, tend)) {
        [[unroll]] for (uint k = 0u; k < ROUND_LEAVES; k++) {
            if (found == k) leaf[k] = uvec3(t, tend - t, meet);
        }
        found++;
    }
}

// Triangle j of the round's leaf k: its first table texel and the rays that met its leaf;
// the cursor (k, j) moves to the next triangle.
uvec2 round_triangle(uvec3 leaf[ROUND_LEAVES], inout uint k, inout uint j) {
    uvec3 lf = leaf[0];
    [[unroll]] for (uint i = 1u; i < ROUND_LEAVES; i++) {
        if (k == i) lf = leaf[i];
    }
    uvec2 tri = uvec2(TRI_BASE + 3u * (lf.x + j), lf.z);
    j++;
    if (j == lf.y) {
        j = 0u;
        k++;
    }
    return tri;
}
#endif
