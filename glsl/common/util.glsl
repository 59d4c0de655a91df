// Small helpers shared by every kernel.
#ifndef VKSHADE_UTIL_GLSL
#define VKSHADE_UTIL_GLSL

// Linear index of this invocation in a 1D dispatch.
uint linear_id() { return gl_GlobalInvocationID.x; }

// PCG-style integer hash (one round): decorrelates per-invocation seeds.
uint hash_u32(uint v) {
    uint state = v * 747796405u + 2891336453u;
    uint word = ((state >> ((state >> 28u) + 4u)) ^ state) * 277803737u;
    return (word >> 22u) ^ word;
}

// Uniform float in [0, 1) from a hash.
float unit_float(uint h) { return float(h >> 8) * (1.0 / 16777216.0); }

// Texel t of a table laid out in rows of `row` texels: (t % row, t / row). The kernels pass
// `row` as a specialization constant (NODE_ROW, CTA_ROW, SRBF_ROW: kernels::table_row) or a
// plain one (BVH_ROW, VERTEX_ROW), so the division is by a constant.
ivec2 table_texel(uint t, uint row) { return ivec2(int(t % row), int(t / row)); }

#endif
