#version 450
// Pass `vertex list`: this frame's vertex list, the vertices a frame's per-vertex passes must
// shade (src/kernels/raster/vertices.rs): every vertex of a triangle pass `vertex mark` found
// covering a pixel, and every vertex of the static mask `always` (e.g. the skin's,
// whose texture-space passes read them wherever the camera looks). One workgroup (no global
// counter to reset between frames); it clears both bitmaps as it reads them, so they start
// the next frame empty.
// The list (`listed`): head = (ceil(count / 64), 1, 1, count), a VkDispatchIndirectCommand
// of one 64-lane workgroup per 64 listed vertices, then the `count` vertex ids: by rank within
// each run of 32 ranks, the runs in no deterministic order (shared atomics); each vertex is
// listed once, and every pass over the list computes each vertex on its own.
// The subset list (`sub_listed`, the same layout): the marked vertices (those of covered
// triangles) that the static mask `subset` holds, e.g. the cloth's, for a pass that reads
// them only at covered triangles (`btf env vertices`); empty while the mask is.
layout(local_size_x = 256) in;

layout(push_constant) uniform Push {
    uint triangle_count;
    uint vertex_count;
} pc;

layout(std430, set = 0, binding = 0) buffer Covered { uint w[]; } covered;
// The rasteriser's triangles: vertex ids (xyz), part id.
layout(std430, set = 0, binding = 1) readonly buffer Triangles { uvec4 t[]; } triangles;
layout(std430, set = 0, binding = 2) buffer Marked { uint w[]; } marked;
layout(std430, set = 0, binding = 3) readonly buffer Always { uint w[]; } always;
layout(std430, set = 0, binding = 4) writeonly buffer Listed { uint head[4]; uint v[]; } listed;
// The order of the list: the vertex of rank r, and the rank of vertex v (a permutation,
// e.g. along a Morton curve, so that a pass's lanes over the list are neighbours). The
// bitmaps `marked` and `always` are indexed by rank.
layout(std430, set = 0, binding = 5) readonly buffer Order { uint v[]; } order;
layout(std430, set = 0, binding = 6) readonly buffer Rank { uint r[]; } rank;
layout(std430, set = 0, binding = 7) readonly buffer Subset { uint w[]; } subset;
layout(std430, set = 0, binding = 8) writeonly buffer SubListed { uint head[4]; uint v[]; } sub_listed;

shared uint count;
shared uint sub_count;

void mark(uint v) {
    if (v >= pc.vertex_count) return;
    uint r = rank.r[v];
    atomicOr(marked.w[r >> 5u], 1u << (r & 31u));
}

void main() {
    uint lid = gl_LocalInvocationIndex;
    if (lid == 0u) {
        count = 0u;
        sub_count = 0u;
    }
    uint tri_words = (pc.triangle_count + 31u) / 32u;
    for (uint w = lid; w < tri_words; w += 256u) {
        uint bits = covered.w[w];
        if (bits == 0u) continue;
        covered.w[w] = 0u;
        while (bits != 0u) {
            uint b = uint(findLSB(bits));
            bits &= bits - 1u;
            uvec4 t = triangles.t[w * 32u + b];
            mark(t.x);
            mark(t.y);
            mark(t.z);
        }
    }
    memoryBarrierBuffer();
    memoryBarrierShared();
    barrier();
    uint vertex_words = (pc.vertex_count + 31u) / 32u;
    for (uint w = lid; w < vertex_words; w += 256u) {
        uint m = marked.w[w];
        uint bits = m | always.w[w];
        if (m != 0u) marked.w[w] = 0u;
        if (bits == 0u) continue;
        uint sub = m & subset.w[w];
        if (sub != 0u) {
            uint at = atomicAdd(sub_count, uint(bitCount(sub)));
            while (sub != 0u) {
                uint b = uint(findLSB(sub));
                sub &= sub - 1u;
                sub_listed.v[at++] = order.v[w * 32u + b];
            }
        }
        uint at = atomicAdd(count, uint(bitCount(bits)));
        while (bits != 0u) {
            uint b = uint(findLSB(bits));
            bits &= bits - 1u;
            listed.v[at++] = order.v[w * 32u + b];
        }
    }
    memoryBarrierShared();
    barrier();
    if (lid == 0u) {
        listed.head[0] = (count + 63u) / 64u;
        listed.head[1] = 1u;
        listed.head[2] = 1u;
        listed.head[3] = count;
        sub_listed.head[0] = (sub_count + 63u) / 64u;
        sub_listed.head[1] = 1u;
        sub_listed.head[2] = 1u;
        sub_listed.head[3] = sub_count;
    }
}
