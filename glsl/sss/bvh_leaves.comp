#version 450
// Per-frame BVH of a skinned mesh, step 1 (pass `sss bvh leaves`), on the skin's vertex frames
// of this pose (`verts`, mm): glsl/common/bvh_leaves.glsl. Pass `sss bvh refit` then fits the
// inner nodes. The CPU twin is posed::refit.
layout(local_size_x = 64) in;

const uint BVH_ROW = 1024u;

layout(std430, set = 0, binding = 0) readonly buffer Verts { vec4 v[]; } verts;
#define BVH_VERTEX(i) verts.v[2u * (i)].xyz
#include <common/bvh_leaves.glsl>
