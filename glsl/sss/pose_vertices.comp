#version 450
#include <common/util.glsl>
// Per-frame geometry of a skinned mesh, step 1 (pass `sss pose vertices`): the vertex frames
// the other passes read (`verts`: position in mm, unit normal), from the posed vertex buffers
// (model units, vec4 per vertex). Each vertex takes the posed position of the first vertex at
// its rest position (`weld`, built once: copies split along UV seams stay bitwise together).
// The CPU twin is src/kernels/sss/cpu.rs vertex_frames of the CPU-posed mesh.
layout(local_size_x = 64) in;

layout(push_constant) uniform Push {
    uint vertices;
    float mm;      // millimetres per model unit
} pc;

layout(std430, set = 0, binding = 0) readonly buffer Positions { vec4 v[]; } posed_pos;
layout(std430, set = 0, binding = 1) readonly buffer Normals { vec4 v[]; } posed_nrm;
layout(std430, set = 0, binding = 2) readonly buffer Weld { uint v[]; } weld;
layout(std430, set = 0, binding = 3) writeonly buffer Verts { vec4 v[]; } verts; // pos, normal
// The same as an image, vertex v at texels 2v, 2v + 1 (BVH_ROW a row), for the per-texel and
// per-triangle passes: lavapipe fetches an image texel's four channels at once, while a
// storage-buffer load at a per-lane index loops over the lanes for each component.
const uint BVH_ROW = 1024u;
layout(set = 0, binding = 4, rgba32f) writeonly uniform image2D vframes;

void main() {
    uint v = gl_GlobalInvocationID.x;
    if (v >= pc.vertices) return;
    vec3 p = posed_pos.v[weld.v[v]].xyz * pc.mm;
    vec3 n = posed_nrm.v[v].xyz;
    float l = length(n);
    n = l > 0.0 ? n * (1.0 / l) : vec3(0.0);
    verts.v[2u * v] = vec4(p, 0.0);
    verts.v[2u * v + 1u] = vec4(n, 0.0);
    uint k = 2u * v;
    imageStore(vframes, table_texel(k, BVH_ROW), vec4(p, 0.0));
    imageStore(vframes, table_texel((k + 1u), BVH_ROW), vec4(n, 0.0));
}
