#ifndef VKSHADE_ENV_TRACE_GLSL
#define VKSHADE_ENV_TRACE_GLSL
// The posed character's own visibility per vertex by ray casting (pass `env trace`): the
// fraction of GRID x GRID stratified cosine-weighted rays from the vertex (origin moved
// `offset` along the normal) that escape the posed mesh, through the BVH refitted this frame
// (passes `env bvh leaves`, `env bvh refit`), and which rays escaped (bit k of word k / 32 of
// the vertex's ceil(GRID^2 / 32) words). `env shadow_rays` corrects the caps' split per lobe
// with them (src/kernels/env/mod.rs). Twin: kernels::env::cpu::traced_rays, the same integer
// hash and f32 operations (sin and cos may differ in the last bits, so a ray grazing an edge
// may decide differently).
#include <common/util.glsl>
#include <env/rays.glsl>
layout(local_size_x = 64) in;

const uint BVH_ROW = 1024u;

layout(push_constant) uniform Push {
    uint vertex_count;
    uint grid;
    float offset;
    uint seed;
} pc;

layout(std430, set = 0, binding = 0) readonly buffer Positions { vec4 p[]; } pos;
layout(std430, set = 0, binding = 1) readonly buffer Normals { vec4 n[]; } nrm;
layout(set = 0, binding = 2, rgba32ui) readonly uniform uimage2D nodes;
layout(set = 0, binding = 3, rgba32ui) readonly uniform uimage2D tris;
layout(std430, set = 0, binding = 4) writeonly buffer Traced { float v[]; } traced;
layout(std430, set = 0, binding = 5) writeonly buffer Escaped { uint w[]; } escaped;

#include <common/bvh.glsl>
#include <env/listed.glsl>

void main() {
    uint vi;
    if (!listed_vertex(gl_GlobalInvocationID.x, vi)) return;
    vec3 p = pos.p[vi].xyz;
    vec3 n = nrm.n[vi].xyz;
    vec3 t, bt;
    ray_basis(n, t, bt);
    vec3 o = p + n * pc.offset;
    uint g = pc.grid;
    uint rays = g * g;
    uint words = (rays + 31u) / 32u;
    float inf = uintBitsToFloat(0x7f800000u);
    uint count = 0u;
    uint word = 0u;
    for (uint k = 0u; k < rays; k++) {
        vec3 d = ray_direction(vi, k, g, pc.seed, t, bt, n);
        if (!any_hit(o, d, inf)) {
            count++;
            word |= 1u << (k & 31u);
        }
        if ((k & 31u) == 31u || k + 1u == rays) {
            escaped.w[vi * words + k / 32u] = word;
            word = 0u;
        }
    }
    traced.v[vi] = float(count) / float(rays);
}
#endif
