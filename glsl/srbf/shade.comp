#version 450
#include <common/util.glsl>
// Per-vertex shading with clustered-PCA transfer: L_o,v = albedo * (p_c,0 + sum_i w_vi p_c,i),
// p the lighting projected onto the rows of the vertex's cluster c (pass `srbf project`).
// Vertices are sorted by cluster and every workgroup holds vertices of one cluster only
// (slots padded per cluster), so the cluster and every row index are uniform across the
// workgroup, and only the weights are streamed, in half precision, eight per uvec4,
// group-major: w8[g * slots + slot], neighbouring invocations reading neighbouring uvec4s
// (half the loads of f32 weights: on lavapipe every per-lane load is a gather). The projected
// rows are an image (one texel a row, written by `srbf project`): lavapipe turns a
// uniform-buffer read at a run-time index into one scalar load per lane and component, an
// image load into one vector gather (the pass took 0.55-0.6 ms on the bunny instead of
// 0.72-0.74). A padding slot (vertex index ~0u) computes and writes nothing.
// Compact lobes (src/kernels/srbf/sharp.rs) add sum_t weight_t V(w_t) max(0, n . w_t) over the
// taps of pass `srbf sharp` (a uniform buffer read at uniform indices), from the vertex's
// normal and visibility bits (word-major over slots: bits[word * slots + slot], so that a
// workgroup reads 64 neighbouring words). Branch-free: a bit is a factor 0 or 1.
layout(local_size_x = 64) in;

layout(push_constant) uniform Push {
    vec4 albedo;   // rgb
    uint slots;    // 64 x workgroups
    uint stride;   // projected rows per cluster: 1 + 8 * GROUPS
} pc;

layout(std430, set = 0, binding = 0) readonly buffer Weights { uvec4 w[]; } weights;
layout(std430, set = 0, binding = 1) readonly buffer Slots { uint v[]; } slot_vertex;
// The cluster of each workgroup, four per uvec4. A uniform buffer: read at a uniform index it
// is a scalar load whose result the compiler knows is uniform, so the row indices derived
// from it are too (a storage-buffer load here made every projected row a per-lane gather on
// lavapipe: 7x slower uncompressed).
const uint MAX_GROUPS = 16384u;
layout(std140, set = 0, binding = 2) uniform Groups { uvec4 c[MAX_GROUPS / 4u]; } group_cluster;
layout(set = 0, binding = 3, rgba32f) uniform readonly image2D projected;  // SRBF_ROW a row
layout(constant_id = 0) const uint SRBF_ROW = 4096u; // kernels::table_row
// The loops' counts are specialization constants, so that the driver unrolls them: on
// lavapipe a loop costs its mask bookkeeping every iteration and its code even when no lane
// enters it (push-constant counts: shade 0.56-0.57 ms on the bunny; constants 0.42-0.43).
layout(constant_id = 1) const uint GROUPS = 2u; // ceil(components / 8)
layout(constant_id = 2) const uint TAPS = 0u;   // compact taps (sharp::tap_count; rays: one a lobe)

vec3 projected_row(uint k) {
    return imageLoad(projected, table_texel(k, SRBF_ROW)).rgb;
}
layout(std430, set = 0, binding = 4) writeonly buffer Radiance { vec4 v[]; } radiance;
layout(std430, set = 0, binding = 5) readonly buffer Normals { vec4 v[]; } normals;  // per slot
layout(std430, set = 0, binding = 6) readonly buffer Visible { uint w[]; } visible;
const uint MAX_TAPS = 128u;   // pack::MAX_TAPS: sharp::MAX_LOBES x sharp::SPREAD_TAPS
// Pass `srbf sharp`'s output, two vec4 per tap: (direction xyz, texel index as a float),
// (weight rgb, 0).
layout(std140, set = 0, binding = 7) uniform Taps { vec4 v[2u * MAX_TAPS]; } taps;

void main() {
    uint slot = gl_GlobalInvocationID.x;
    if (slot >= pc.slots) return;
    uint vertex = slot_vertex.v[slot];
    uint group = gl_WorkGroupID.x;
    uint base = group_cluster.c[group / 4u][group % 4u] * pc.stride;
    vec3 sum = projected_row(base);
    uint index = slot;
    for (uint g = 0u; g < GROUPS; g++) {
        uvec4 h = weights.w[index];
        vec2 a = unpackHalf2x16(h.x);
        vec2 b = unpackHalf2x16(h.y);
        vec2 c = unpackHalf2x16(h.z);
        vec2 d = unpackHalf2x16(h.w);
        uint k = base + 1u + 8u * g;
        sum += a.x * projected_row(k) + a.y * projected_row(k + 1u)
            + b.x * projected_row(k + 2u) + b.y * projected_row(k + 3u)
            + c.x * projected_row(k + 4u) + c.y * projected_row(k + 5u)
            + d.x * projected_row(k + 6u) + d.y * projected_row(k + 7u);
        index += pc.slots;
    }
    if (TAPS > 0u) {
        vec3 n = normals.v[slot].xyz;
        for (uint t = 0u; t < TAPS; t++) {
            vec4 d = taps.v[2u * t];
            uint texel = uint(d.w);
            uint bits = visible.w[(texel >> 5u) * pc.slots + slot];
            float seen = float((bits >> (texel & 31u)) & 1u);
            sum += taps.v[2u * t + 1u].rgb * (seen * max(dot(n, d.xyz), 0.0));
        }
    }
    if (vertex != 0xFFFFFFFFu) {
        radiance.v[vertex] = vec4(pc.albedo.rgb * sum, 1.0);
    }
}
