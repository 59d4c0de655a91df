#version 450
#include <common/util.glsl>
// Per-frame geometry of a skinned mesh, step 3 (pass `sss pose texels`): per texel of the
// occupied row segments, its position (mm) and flag, its unit normal and area, from its
// triangle and the barycentrics of its centre (fixed by the UV layout, `source`), the vertex
// frames of this pose (`vframes`) and the triangle's face normal and texel area (`trirec`,
// pass `sss pose triangles`). Gutter texels repeat their source texel's triangle and
// barycentrics (so its position and normal) with area 0. Empty texels are never written.
// The CPU twin is src/scene/texspace.rs (TexGeometry::build of the posed mesh).
layout(local_size_x = 8, local_size_y = 8) in;

layout(push_constant) uniform Push {
    uint size;
    uint tiles;
} pc;

const uint BVH_ROW = 1024u;
const uint TILE_ROW = 256u;
const float COVERED = 1.0;

layout(set = 0, binding = 0, rgba32ui) readonly uniform uimage2D source; // tri, w1, w2, flag
layout(set = 0, binding = 1, rgba32ui) readonly uniform uimage2D corners; // v0, v1, v2, -
layout(set = 0, binding = 2, rgba32f) readonly uniform image2D trirec;   // face n, area
// The vertex frames (position mm, normal), vertex v at texels 2v, 2v + 1 (pass `sss pose
// vertices`).
layout(set = 0, binding = 3, rgba32f) readonly uniform image2D vframes;
layout(set = 0, binding = 4, rgba32f) writeonly uniform image2D pos;     // xyz, flag
layout(set = 0, binding = 5, rgba32f) writeonly uniform image2D nrm;     // xyz, area
layout(std430, set = 0, binding = 6) readonly buffer Tiles { uint v[]; } tiles;

vec3 vload(uint k) {
    return imageLoad(vframes, table_texel(k, BVH_ROW)).xyz;
}

void main() {
    uint ti = 8u * (gl_WorkGroupID.y * TILE_ROW + gl_WorkGroupID.x) + gl_LocalInvocationID.y;
    if (ti >= pc.tiles) return;
    uint tile = tiles.v[ti];
    uvec2 xy = uvec2((tile & 0xffffu) * 8u + gl_LocalInvocationID.x, tile >> 16u);
    if (xy.x >= pc.size || xy.y >= pc.size) return;
    ivec2 at = ivec2(xy);
    uvec4 s = imageLoad(source, at);
    float flag = uintBitsToFloat(s.w);
    if (flag == 0.0) return;
    uvec4 c = imageLoad(corners, at);
    float w1 = uintBitsToFloat(s.y), w2 = uintBitsToFloat(s.z);
    float w0 = 1.0 - w1 - w2;
    vec3 p = vload(2u * c.x) * w0 + vload(2u * c.y) * w1 + vload(2u * c.z) * w2;
    vec3 n = vload(2u * c.x + 1u) * w0 + vload(2u * c.y + 1u) * w1 + vload(2u * c.z + 1u) * w2;
    vec4 tr = imageLoad(trirec, table_texel(s.x, BVH_ROW));
    float l = length(n);
    n = l > 0.0 ? n * (1.0 / l) : tr.xyz;
    imageStore(pos, at, vec4(p, flag));
    imageStore(nrm, at, vec4(n, flag == COVERED ? tr.w : 0.0));
}
