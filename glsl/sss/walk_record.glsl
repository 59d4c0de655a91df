// The surface walk's per-triangle records (src/kernels/sss/walk.rs, SurfaceWalk::records),
// read by the diffusion (common/sss_diffusion.glsl) and by pass `sss reach boxes`
// (sss/reach_boxes.comp); pass `sss pose triangles` writes them for a posed kernel. Per
// triangle, WALK_RECORD texels, WALK_ROW texels a row: (1 / l1, x2, 1 / y2, edge kinds),
// (uv0, uv1 - uv0), (uv2 - uv0, region, 0), then per edge the map from this triangle's
// barycentrics to the atlas through the neighbour unfolded across that edge:
// uv = s + V (b1, b2), (V row-major), (s, 0, 0). Edge kinds: 2 bits an edge, EDGE_* below.
#ifndef VKSHADE_SSS_WALK_RECORD_GLSL
#define VKSHADE_SSS_WALK_RECORD_GLSL

layout(set = 0, binding = 2, rgba32ui) readonly uniform uimage2D walk;

const uint WALK_ROW = 1024u;
const uint WALK_RECORD = 9u;
const uint EDGE_SHARED = 0u; // walk::EDGE_*
const uint EDGE_OPEN = 1u;

// Texel k of triangle tri's record.
uvec4 record(uint tri, uint k) {
    uint i = tri * WALK_RECORD + k;
    return imageLoad(walk, ivec2(i % WALK_ROW, i / WALK_ROW));
}
#endif
