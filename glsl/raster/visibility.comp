#version 450
#extension GL_ARB_gpu_shader_int64 : require
#extension GL_EXT_shader_atomic_int64 : require
#extension GL_EXT_control_flow_attributes : require
// The visibility pass of the compute rasteriser: one invocation per triangle (any number of
// triangles: the grid is 2D, rows of `row` invocations). Each triangle is projected through
// the pinhole camera, clipped against the near plane (one Sutherland-Hodgman pass: up to two
// sub-triangles), snapped to 1/256 px and scanned over its screen bounding box with integer
// edge functions and the top-left rule; every covered pixel centre takes
//   key = (floatBits(view depth) << 32) | triangle
// by atomicMin: the nearest triangle wins, the lowest id on exact ties. View depth is the
// distance along the camera's forward axis; it is positive, so its float bits order like
// the values. 1/depth is affine in screen space: depth = 1 / sum_i b_i / z_i.
// Both windings are rasterised (back faces are kept; the resolve pass flips their normal).
// Every covered pixel also flags its 16 x 4 tile (the same value from any invocation), from
// which `raster tiles` lists the tiles the later passes dispatch over.
layout(local_size_x = 64) in;
#include <common/tiles.glsl>

layout(push_constant) uniform Push {
    vec4 eye;      // xyz: camera position (model units); w: near plane distance
    vec4 forward;  // xyz: unit view axis
    vec4 right;    // xyz: camera right / (tan(fov_y / 2) * aspect): x_ndc = dot(q, right) / z
    vec4 up;       // xyz: camera up / tan(fov_y / 2): y_ndc = dot(q, up) / z
    uvec4 dims;    // width, height, triangle count, invocations per grid row
} pc;

layout(std430, set = 0, binding = 0) readonly buffer Positions { vec4 p[]; } pos;
layout(std430, set = 0, binding = 1) readonly buffer Triangles { uvec4 t[]; } tris;
layout(std430, set = 0, binding = 2) buffer Visibility { uint64_t key[]; } vis;
// 0: triangles scanned, 1: clipped by the near plane, 2: wholly behind it, 3: outside the
// guard band, 4: back-facing (scanned), 5: zero screen area, 6: off screen.
layout(std430, set = 0, binding = 3) buffer Counters { uint c[8]; } counters;
// One word per 16 x 4 tile (ty * tiles_x + tx): 1 where a pixel is covered.
layout(std430, set = 0, binding = 4) writeonly buffer TileFlags { uint f[]; } flags;

const float SUB = 256.0;          // sub-pixel steps per pixel
const float GUARD = 16384.0;      // |screen coordinate| limit in pixels: products < 2^47

// A vertex in view space: (x_ndc * z, y_ndc * z, z).
vec3 to_view(vec3 p) {
    vec3 q = p - pc.eye.xyz;
    return vec3(dot(q, pc.right.xyz), dot(q, pc.up.xyz), dot(q, pc.forward.xyz));
}

// Screen position in pixels (y down) and depth.
vec3 to_screen(vec3 v) {
    vec2 ndc = v.xy / v.z;
    return vec3((ndc.x + 1.0) * 0.5 * float(pc.dims.x), (1.0 - ndc.y) * 0.5 * float(pc.dims.y), v.z);
}

int64_t edge(i64vec2 a, i64vec2 b, i64vec2 p) {
    return (b.x - a.x) * (p.y - a.y) - (b.y - a.y) * (p.x - a.x);
}

// Top-left rule, for an edge a -> b of a triangle oriented so that inside is E >= 0 (y
// down): a top edge is horizontal with the inside below (dx > 0), a left edge goes up
// (dy < 0). Samples exactly on other edges are not covered: bias -1.
int64_t bias(i64vec2 a, i64vec2 b) {
    i64vec2 d = b - a;
    bool top = d.y == 0l && d.x > 0l;
    bool left = d.y < 0l;
    return (top || left) ? 0l : -1l;
}

void scan(vec3 s0, vec3 s1, vec3 s2, uint id) {
    if (any(greaterThan(abs(vec3(s0.x, s1.x, s2.x)), vec3(GUARD)))
        || any(greaterThan(abs(vec3(s0.y, s1.y, s2.y)), vec3(GUARD)))) {
        atomicAdd(counters.c[3], 1u);
        return;
    }
    i64vec2 a = i64vec2(round(s0.xy * SUB));
    i64vec2 b = i64vec2(round(s1.xy * SUB));
    i64vec2 c = i64vec2(round(s2.xy * SUB));
    vec3 iz = vec3(1.0 / s0.z, 1.0 / s1.z, 1.0 / s2.z);
    int64_t area = edge(a, b, c);
    if (area == 0l) {
        atomicAdd(counters.c[5], 1u);
        return;
    }
    if (area < 0l) {   // orient so that inside is E >= 0
        i64vec2 t = b; b = c; c = t;
        iz = iz.xzy;
        area = -area;
    }
    int x0 = max(int(floor(float(min(a.x, min(b.x, c.x))) / SUB)), 0);
    int x1 = min(int(ceil(float(max(a.x, max(b.x, c.x))) / SUB)), int(pc.dims.x) - 1);
    int y0 = max(int(floor(float(min(a.y, min(b.y, c.y))) / SUB)), 0);
    int y1 = min(int(ceil(float(max(a.y, max(b.y, c.y))) / SUB)), int(pc.dims.y) - 1);
    if (x0 > x1 || y0 > y1) {
        atomicAdd(counters.c[6], 1u);
        return;
    }
    atomicAdd(counters.c[0], 1u);
    int64_t b0 = bias(b, c), b1 = bias(c, a), b2 = bias(a, b);
    // Edge values at the first sample and their steps along x and y.
    i64vec2 p = i64vec2(int64_t(x0) * 256l + 128l, int64_t(y0) * 256l + 128l);
    int64_t r0 = edge(b, c, p) + b0, r1 = edge(c, a, p) + b1, r2 = edge(a, b, p) + b2;
    int64_t dx0 = -(c.y - b.y) * 256l, dx1 = -(a.y - c.y) * 256l, dx2 = -(b.y - a.y) * 256l;
    int64_t dy0 = (c.x - b.x) * 256l, dy1 = (a.x - c.x) * 256l, dy2 = (b.x - a.x) * 256l;
    float inv_area = 1.0 / float(area);
    // One loop over the box's pixels, row by row: the lanes of a SIMD step scan boxes of
    // different shapes, and nested loops over rows and columns ran the tallest lane's rows
    // times the widest lane's columns; one loop runs the largest lane's pixel count.
    uint width = uint(x1 - x0 + 1);
    uint count = width * uint(y1 - y0 + 1);
    int x = x0, y = y0;
    int64_t e0 = r0, e1 = r1, e2 = r2;
    // The last tile this invocation flagged: a tile's flag is stored only when it differs
    // from that one, once per run of covered pixels in a tile (a storage-buffer store at a
    // per-lane address runs lane by lane on lavapipe; flagging every covered pixel cost
    // ~0.17 of the pass's ~1.85 ms).
    uint flagged = ~0u;
    for (uint k = 0u; k < count; k++) {
        if (e0 >= 0l && e1 >= 0l && e2 >= 0l) {
            // The bias is removed from the barycentrics (it only decides ties).
            vec3 w = vec3(float(e0 - b0), float(e1 - b1), float(e2 - b2)) * inv_area;
            float depth = 1.0 / dot(w, iz);
            uint64_t key = (uint64_t(floatBitsToUint(depth)) << 32) | uint64_t(id);
            atomicMin(vis.key[uint(y) * pc.dims.x + uint(x)], key);
            uint tile = tile_of(uvec2(x, y), pc.dims.x);
            if (tile != flagged) {
                flags.f[tile] = 1u;
                flagged = tile;
            }
        }
        bool row_end = x == x1;
        r0 += row_end ? dy0 : 0l;
        r1 += row_end ? dy1 : 0l;
        r2 += row_end ? dy2 : 0l;
        e0 = row_end ? r0 : e0 + dx0;
        e1 = row_end ? r1 : e1 + dx1;
        e2 = row_end ? r2 : e2 + dx2;
        y += row_end ? 1 : 0;
        x = row_end ? x0 : x + 1;
    }
}

// Appends x to the clipped polygon (q0, q1, q2, q3) of n vertices: a select per slot, so
// that the polygon stays in registers (an array at a lane's own index n would live in
// per-lane memory).
void append(vec3 x, inout vec3 q0, inout vec3 q1, inout vec3 q2, inout vec3 q3, inout uint n) {
    q0 = n == 0u ? x : q0;
    q1 = n == 1u ? x : q1;
    q2 = n == 2u ? x : q2;
    q3 = n == 3u ? x : q3;
    n++;
}

void main() {
    uint id = gl_GlobalInvocationID.y * pc.dims.w + gl_GlobalInvocationID.x;
    if (gl_GlobalInvocationID.x >= pc.dims.w || id >= pc.dims.z) return;
    uvec4 t = tris.t[id];
    vec3 v[3] = vec3[3](to_view(pos.p[t.x].xyz), to_view(pos.p[t.y].xyz), to_view(pos.p[t.z].xyz));
    float near = pc.eye.w;
    // Back-facing: the geometric normal cross(b - a, c - a) faces away from the eye. The
    // view basis (right, up, forward) is left-handed, so in its coordinates the cross
    // product is the world one negated: front faces have dot(vn, v0) > 0.
    vec3 vn = cross(v[1] - v[0], v[2] - v[0]);
    uint inside = uint(v[0].z >= near) + uint(v[1].z >= near) + uint(v[2].z >= near);
    if (inside == 0u) {
        atomicAdd(counters.c[2], 1u);
        return;
    }
    if (dot(vn, v[0]) < 0.0) atomicAdd(counters.c[4], 1u);
    if (inside < 3u) atomicAdd(counters.c[1], 1u);
    // Sutherland-Hodgman against z >= near: walk the edges, keep inside vertices and the
    // crossings; a triangle wholly in front keeps (v0, v1, v2). Every triangle takes this
    // path and one loop over the (up to two) sub-triangles scans them, so that `scan` is
    // inlined once: lavapipe ran the clipped path's two further copies under a lane mask
    // for every triangle, clipped or not (~0.34 of the pass's ~1.85 ms by ablation; with the
    // tile flags' runs above, 1.88 -> 1.57 ms, fastest of 6 alternated `bench frame` runs;
    // the same keys, counters and flags: tests/raster.rs). The edge loop is unrolled, so
    // `v` is read at constant indices only.
    vec3 q0 = v[0], q1 = v[1], q2 = v[2], q3 = v[2];
    uint n = 0u;
    [[unroll]] for (uint i = 0u; i < 3u; i++) {
        vec3 a = v[i], b = v[(i + 1u) % 3u];
        bool ain = a.z >= near, bin = b.z >= near;
        if (ain) append(a, q0, q1, q2, q3, n);
        if (ain != bin) append(mix(a, b, (near - a.z) / (b.z - a.z)), q0, q1, q2, q3, n);
    }
    vec3 s0 = to_screen(q0);
    for (uint sub = 0u; sub < n - 2u; sub++) {
        scan(s0, to_screen(sub == 0u ? q1 : q2), to_screen(sub == 0u ? q2 : q3), id);
    }
}
