#version 450
// The posed character's own visibility per vertex by ray casting (pass `env trace`): the
// fraction of GRID x GRID stratified cosine-weighted rays from the vertex (origin moved
// `offset` along the normal) that escape the posed mesh, through the BVH refitted this frame
// (passes `env bvh leaves`, `env bvh refit`). `env shadow` takes it in place of AO's
// visibility (src/kernels/env/mod.rs). Twin: kernels::env::cpu::traced_visibility, the same
// integer hash and f32 operations (sin and cos may differ in the last bits, so a ray grazing
// an edge may decide differently).
#include <common/util.glsl>
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

#include <common/bvh.glsl>

void main() {
    uint vi = gl_GlobalInvocationID.x;
    if (vi >= pc.vertex_count) return;
    vec3 p = pos.p[vi].xyz;
    vec3 n = nrm.n[vi].xyz;
    // geom::orthonormal_basis (Duff et al. 2017); copysign(1, n.z) keeps -0.0's sign.
    float sgn = (floatBitsToUint(n.z) >> 31u) != 0u ? -1.0 : 1.0;
    float a = -1.0 / (sgn + n.z);
    float b = n.x * n.y * a;
    vec3 t = vec3(1.0 + sgn * n.x * n.x * a, sgn * b, -sgn * n.x);
    vec3 bt = vec3(b, sgn + n.y * n.y * a, -n.y);
    vec3 o = p + n * pc.offset;
    uint g = pc.grid;
    uint rays = g * g;
    float inf = uintBitsToFloat(0x7f800000u);
    uint escaped = 0u;
    for (uint k = 0u; k < rays; k++) {
        uint key = pc.seed ^ (vi * rays + k) * 2u;
        float u1 = (float(k / g) + unit_float(hash_u32(key))) / float(g);
        float u2 = (float(k % g) + unit_float(hash_u32(key + 1u))) / float(g);
        u1 = min(u1, 0.999999);
        float r = sqrt(u1);
        float phi = 6.2831855 * u2;
        vec3 l = vec3(r * cos(phi), r * sin(phi), sqrt(max(1.0 - u1, 0.0)));
        vec3 d = t * l.x + bt * l.y + n * l.z;
        if (!any_hit(o, d, inf)) escaped++;
    }
    traced.v[vi] = float(escaped) / float(rays);
}
