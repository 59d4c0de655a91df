// Where the triangles start in the BVH's table (glsl/common/bvh.glsl has the layout): a
// specialization constant of every module that traverses or builds the table, set from
// src/geom/bvh.rs `tri_base`. Included by common/bvh.glsl and common/bvh_leaves.glsl.
#ifndef VKSHADE_BVH_TABLE_GLSL
#define VKSHADE_BVH_TABLE_GLSL
layout(constant_id = 16) const uint TRI_BASE = 0u;
#endif
