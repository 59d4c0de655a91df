#version 450
// Per-frame BVH of the posed character, step 1 (pass `env bvh leaves`), on the pose kernel's
// positions (model units): glsl/common/bvh_leaves.glsl. Pass `env bvh refit` (the module
// sss/bvh_refit) then fits the inner nodes. The CPU twin is kernels::sss::posed::refit.
layout(local_size_x = 64) in;

const uint BVH_ROW = 1024u;

layout(std430, set = 0, binding = 0) readonly buffer Positions { vec4 p[]; } pos;
#define BVH_VERTEX(i) pos.p[i].xyz
#include <common/bvh_leaves.glsl>
