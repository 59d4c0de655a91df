// The rays of pass `env trace`, shared with `env shadow_rays` (which re-derives each ray's
// direction to weigh it per lobe): grid x grid stratified cosine-weighted directions per
// vertex, jittered by an integer hash of (seed, vertex, ray). Twin: kernels::env::cpu::
// ray_directions, the same integer hash and f32 operations (sin and cos may differ in the
// last bits on a device).
#ifndef VKSHADE_ENV_RAYS_GLSL
#define VKSHADE_ENV_RAYS_GLSL
#include <common/util.glsl>

// geom::orthonormal_basis (Duff et al. 2017); copysign(1, n.z) keeps -0.0's sign.
void ray_basis(vec3 n, out vec3 t, out vec3 bt) {
    float sgn = (floatBitsToUint(n.z) >> 31u) != 0u ? -1.0 : 1.0;
    float a = -1.0 / (sgn + n.z);
    float b = n.x * n.y * a;
    t = vec3(1.0 + sgn * n.x * n.x * a, sgn * b, -sgn * n.x);
    bt = vec3(b, sgn + n.y * n.y * a, -n.y);
}

// Ray k of vertex vi (normal n, basis t, bt) of the g x g strata: stratum (row, column) =
// (k % g, k / g), radius^2 by row and azimuth by column, so consecutive rays run down an
// azimuth sector (pass `env trace` walks them a few at a time: a narrow packet enters fewer
// nodes); its jitter is keyed by row * g + column.
vec3 ray_direction(uint vi, uint k, uint g, uint seed, vec3 t, vec3 bt, vec3 n) {
    uint rays = g * g;
    uint row = k % g, col = k / g;
    uint key = seed ^ (vi * rays + row * g + col) * 2u;
    float u1 = (float(row) + unit_float(hash_u32(key))) / float(g);
    float u2 = (float(col) + unit_float(hash_u32(key + 1u))) / float(g);
    u1 = min(u1, 0.999999);
    float r = sqrt(u1);
    float phi = 6.2831855 * u2;
    vec3 l = vec3(r * cos(phi), r * sin(phi), sqrt(max(1.0 - u1, 0.0)));
    return t * l.x + bt * l.y + n * l.z;
}

#endif
