#version 450
// Pass `sss reach mark`, the first step of the reach (SssKernel::set_reach). Over the
// needed list (`sss needed list`, the diffusion's own dispatch shape), each texel marks its
// triangle in `reach_tris` (bit t % 32 of word t / 32), unless the texel to its left holds
// the same one (runs of a triangle along a segment cost one atomic); pass `sss reach boxes`
// marks where that triangle's samples and contact entries read. Texels with no surface name
// no triangle (texspace::NO_TRIANGLE). Each needed segment also marks its own block in
// `reach_blocks` (bit (y / BLOCK_ROWS) * row_segments + x / 8): a texel reads its own E, and
// a gutter texel's centre lies outside its triangle's UV triangle.
layout(local_size_x = 8, local_size_y = 8) in;

layout(push_constant) uniform Push {
    uint size;          // atlas size x size
    uint triangles;     // the mesh's triangles
    uint row_segments;  // ceil(size / 8): blocks a block row
    float radius;       // (pass `sss reach boxes`)
} pc;

layout(set = 0, binding = 1, rgba32ui) readonly uniform uimage2D start;
layout(std430, set = 0, binding = 20) readonly buffer NeededList { uint head[4]; uint v[]; } needed_list;
layout(std430, set = 0, binding = 21) buffer ReachTris { uint w[]; } reach_tris;
layout(std430, set = 0, binding = 22) buffer ReachBlocks { uint w[]; } reach_blocks;

const uint BLOCK_ROWS = 2u; // kernels::sss::pack::REACH_BLOCK_ROWS

shared uint row_tri[8][8];

void main() {
    uvec2 lid = gl_LocalInvocationID.xy;
    uint ti = 8u * (gl_WorkGroupID.y * gl_NumWorkGroups.x + gl_WorkGroupID.x) + lid.y;
    uint tri = 0xffffffffu;
    if (ti < needed_list.head[3]) {
        uint tile = needed_list.v[ti];
        uvec2 xy = uvec2((tile & 0xffffu) * 8u + lid.x, tile >> 16u);
        if (xy.x < pc.size && xy.y < pc.size) {
            tri = imageLoad(start, ivec2(xy)).x;
        }
        if (lid.x == 0u) {
            uint b = (xy.y / BLOCK_ROWS) * pc.row_segments + xy.x / 8u;
            atomicOr(reach_blocks.w[b >> 5u], 1u << (b & 31u));
        }
    }
    row_tri[lid.y][lid.x] = tri;
    barrier();
    if (tri < pc.triangles && (lid.x == 0u || row_tri[lid.y][lid.x - 1u] != tri)) {
        atomicOr(reach_tris.w[tri >> 5u], 1u << (tri & 31u));
    }
}
