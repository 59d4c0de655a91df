#version 450
#extension GL_GOOGLE_include_directive : require
#include <common/util.glsl>
// Pass `sss reach boxes` (SssKernel::set_reach): for each triangle with a texel in a needed
// segment (the caller's bitmap `needed`, through the triangle's list of segments), the
// 8 x BLOCK_ROWS blocks of the atlas its diffusion samples can land in and the blocks of its
// texels' contact entries' sources, marked in `reach_blocks`; and the blocks of its needed
// segments themselves (a texel reads its own E, and a gutter texel's centre lies outside its
// triangle's UV triangle). A texel with no surface starts from no triangle and reads nothing.
//
// A texel of triangle T samples at barycentrics b = w + J p, w its centre's (fixed by the
// UV layout), p the sample's offset in T's plane rotated by the texel's angle, |p| <= R
// (pc.radius: the longest offset of any region's pattern), J from T's 2D frame (walk
// record texel 0: 1 / l1, x2, 1 / y2; glsl/common/sss_diffusion.glsl computes b the same
// way). The landing is read through T's UV map (inside T) or through the map of the edge it
// leaves by (a shared edge; past an open or non-manifold edge nothing is read): uv = t + M b,
// affine in b whichever map. So over every texel and offset the landings of map (t, M) lie
// in the box of t + M c_i over the corners c_i of the region {b1 >= m1, b2 >= m2,
// b0 >= m0} (m: the least barycentrics of T's texel centres, pass-free: uploaded with the
// layout) widened by R |row of M J| per axis, and the texel read is the nearest,
// floor(uv + 0.5): half a texel more, and a margin for the rounding of the two computations.
// Each of the four maps' boxes is marked whether or not a sample leaves through its edge.
// Not finite (a degenerate pose): the whole atlas.
layout(local_size_x = 64) in;

layout(push_constant) uniform Push {
    uint size;
    uint triangles;
    float radius;
} pc;
#include <sss/segments.glsl>

#include <sss/walk_record.glsl>
layout(std430, set = 0, binding = 8) readonly buffer Needed { uint w[]; } needed;
layout(std430, set = 0, binding = 22) buffer ReachBlocks { uint w[]; } reach_blocks;
// Per triangle two entries, (m1, m2, m0 as float bits, n) and (first, k, j, 0); from entry
// first the k blocks of its texels (pass `sss reach triangles`), the j segments they lie
// in, the n blocks of its texels' contact entries' sources (kernels::sss::pack::
// reach_static). REACH_ROW texels a row: an image, as lavapipe loads a texel with one
// gather and a storage buffer's uvec4 at a per-lane index with a loop over the lanes per
// component.
layout(set = 0, binding = 23, rgba32ui) readonly uniform uimage2D reach_static;
const uint REACH_ROW = 1024u; // pack::BVH_ROW

// Entry k of the reach's layout.
uvec4 reach_entry(uint k) {
    return imageLoad(reach_static, table_texel(k, REACH_ROW));
}

const uint BLOCK_ROWS = 4u; // kernels::sss::pack::REACH_BLOCK_ROWS

// Marks the blocks of the texels nearest to the points of [lo, hi].
void mark_box(vec2 lo, vec2 hi) {
    float top = float(pc.size) - 1.0;
    bool finite = !any(isnan(lo)) && !any(isnan(hi)) && !any(isinf(lo)) && !any(isinf(hi));
    vec2 eps = vec2(0.02) + 1e-4 * max(abs(lo), abs(hi));
    vec2 a = finite ? floor(lo + 0.5 - eps) : vec2(0.0);
    vec2 z = finite ? floor(hi + 0.5 + eps) : vec2(top);
    if (a.x > top || a.y > top || z.x < 0.0 || z.y < 0.0) return;
    uvec2 b0 = uvec2(clamp(a, vec2(0.0), vec2(top))) / uvec2(8u, BLOCK_ROWS);
    uvec2 b1 = uvec2(clamp(z, vec2(0.0), vec2(top))) / uvec2(8u, BLOCK_ROWS);
    for (uint by = b0.y; by <= b1.y; by++) {
        uint first = by * ROW_SEGMENTS + b0.x;
        uint last = by * ROW_SEGMENTS + b1.x;
        for (uint w = first >> 5u; w <= last >> 5u; w++) {
            uint lo_bit = w == (first >> 5u) ? (first & 31u) : 0u;
            uint hi_bit = w == (last >> 5u) ? (last & 31u) : 31u;
            uint bits = (0xffffffffu >> (31u - hi_bit)) & (0xffffffffu << lo_bit);
            atomicOr(reach_blocks.w[w], bits);
        }
    }
}

void main() {
    uint t = gl_GlobalInvocationID.x;
    if (t >= pc.triangles) return;
    uvec4 st0 = reach_entry(2u * t);
    uvec4 st1 = reach_entry(2u * t + 1u);
    // Its needed segments' own blocks.
    bool marked = false;
    for (uint c = 0u; c < st1.z; c++) {
        uint s = reach_entry(st1.x + st1.y + c).x;
        if (((needed.w[s >> 5u] >> (s & 31u)) & 1u) == 0u) continue;
        marked = true;
        uint b = (s / ROW_SEGMENTS / BLOCK_ROWS) * ROW_SEGMENTS + s % ROW_SEGMENTS;
        atomicOr(reach_blocks.w[b >> 5u], 1u << (b & 31u));
    }
    if (!marked) return;
    uvec4 ra = record(t, 0u);
    uvec4 rb = record(t, 1u);
    uvec4 rc = record(t, 2u);
    vec3 sh = uintBitsToFloat(ra.xyz);
    uint kinds = ra.w;
    // J: (d1, d2) = J p.
    float j00 = sh.x, j01 = -sh.x * sh.y * sh.z, j11 = sh.z;
    vec3 m = uintBitsToFloat(st0.xyz);
    // The contact entries' sources, read as they are.
    uint first = st1.x + st1.y + st1.z;
    for (uint c = 0u; c < st0.w; c++) {
        uint b = reach_entry(first + c).x;
        atomicOr(reach_blocks.w[b >> 5u], 1u << (b & 31u));
    }
    // Inside T a sample reads through T's own map, at a point of T: its UV triangle.
    vec2 uv0 = uintBitsToFloat(rb.xy), du1 = uintBitsToFloat(rb.zw), du2 = uintBitsToFloat(rc.xy);
    vec2 a1 = uv0 + du1, a2 = uv0 + du2;
    // (widened by 1e-4 of the offsets' reach through this map: the diffusion rounds
    // uvt + mx ux + my uy, whose terms grow with it)
    vec2 h0 = pc.radius * vec2(length(vec2(du1.x * j00, du1.x * j01 + du2.x * j11)),
                               length(vec2(du1.y * j00, du1.y * j01 + du2.y * j11)));
    mark_box(min(uv0, min(a1, a2)) - 1e-4 * h0, max(uv0, max(a1, a2)) + 1e-4 * h0);
    // Texel centres all in T (m >= 0): a sample leaving through edge e crosses it at a
    // point of that edge, at most R before it lands, so its landing is within R of the
    // edge (corners e + 1, e + 2). Otherwise (gutter texels whose centres lie outside T):
    // within R of the region of the centres.
    bool clean = min(m.x, min(m.y, m.z)) >= 0.0;
    vec2 c0 = vec2(m.x, m.y);
    vec2 c1 = vec2(1.0 - m.z - m.y, m.y);
    vec2 c2 = vec2(m.x, 1.0 - m.z - m.x);
    const vec2 corner[3] = vec2[3](vec2(0.0), vec2(1.0, 0.0), vec2(0.0, 1.0));
    for (uint e = 0u; e < 3u; e++) {
        if (((kinds >> (2u * e)) & 3u) != EDGE_SHARED) continue;
        vec4 mm = uintBitsToFloat(record(t, 3u + 2u * e));
        vec2 tt = uintBitsToFloat(record(t, 4u + 2u * e).xy);
        vec2 p0 = clean ? corner[(e + 1u) % 3u] : c0;
        vec2 p1 = clean ? corner[(e + 2u) % 3u] : c1;
        vec2 p2 = clean ? p1 : c2;
        vec2 u0 = tt + vec2(mm.x * p0.x + mm.y * p0.y, mm.z * p0.x + mm.w * p0.y);
        vec2 u1 = tt + vec2(mm.x * p1.x + mm.y * p1.y, mm.z * p1.x + mm.w * p1.y);
        vec2 u2 = tt + vec2(mm.x * p2.x + mm.y * p2.y, mm.z * p2.x + mm.w * p2.y);
        // Rows of M J.
        vec2 r0 = vec2(mm.x * j00, mm.x * j01 + mm.y * j11);
        vec2 r1 = vec2(mm.z * j00, mm.z * j01 + mm.w * j11);
        vec2 h = pc.radius * vec2(length(r0), length(r1));
        mark_box(min(u0, min(u1, u2)) - h, max(u0, max(u1, u2)) + h);
    }
}
