#version 450
#include <common/util.glsl>
// The published variant of sphere AO (Cut::Fixed): per vertex a fixed list of tree nodes,
// chosen once in the bind pose (src/kernels/ao/fixed.rs) and read here at their skinned
// centres; overlap handled pairwise with the 3D table of formula::OverlapTable. Mirrors
// kernels::ao::cpu::CpuAo::fixed_vertex operation for operation.
//
// Per node of the list (largest bind-pose occlusion first): the sphere's occlusion I (2D
// table or closed form, the inside fade as in occlusion.comp), less its overlap with the
// earlier caps of the list: the pairwise overlaps are F(a_i, a_j, g_ij) * min(I_i, I_j),
// where F is the fraction of the smaller cap inside the larger (trilinear lookup), and the
// overlap with their union is taken midway between the largest and the (capped) sum.
#include <common/ao.glsl>
// 32 lanes: the caps below take 32 x 32 x 24 bytes = 24 KiB of shared memory.
layout(local_size_x = 32) in;

layout(constant_id = 0) const bool EXACT = false;        // closed form instead of the table
layout(constant_id = 1) const bool CLAMP_INSIDE = false; // receiver inside a sphere: clamp h
layout(constant_id = 2) const bool CORRECT = true;       // apply the static correction

layout(push_constant) uniform Push {
    uint vertex_count;
    uint slots;
    uint table_n_psi;
    uint table_n_theta;
    uint overlap_n;
} pc;

layout(std430, set = 0, binding = 0) readonly buffer Positions { vec4 p[]; } pos;
layout(std430, set = 0, binding = 1) readonly buffer Normals { vec4 n[]; } nrm;
// The tables and the tree are images (one vector gather a load on lavapipe, where a
// storage-buffer load at a per-lane address is a loop over the lanes), laid out as
// occlusion.comp's: the posed tree two texels a node (glsl/ao/skin.comp; the sphere is texel
// 2n), the 2D table as bilinear quads.
layout(set = 0, binding = 2, rgba32f) uniform readonly image2D nodes;
layout(set = 0, binding = 3, rgba32f) uniform readonly image2D table_quads;
layout(std430, set = 0, binding = 4) readonly buffer Correction { float c[]; } correction;
layout(std430, set = 0, binding = 5) writeonly buffer Visibility { float v[]; } ao;
layout(std430, set = 0, binding = 6) writeonly buffer Stats { uvec2 tested_used[]; } stats;
// Slot-major lists: entry slot * vertex_count + vertex, NODE_ROW texels a row; NO_NODE ends
// a list.
layout(set = 0, binding = 7, r32ui) uniform readonly uimage2D fixed_nodes;
// formula::OverlapTable as quads: texel (i, j, k) holds entries (i, j), (i + 1, j),
// (i, j + 1), (i + 1, j + 1) of slice k, so a trilinear lookup is two image loads.
layout(set = 0, binding = 8, rgba32f) uniform readonly image3D overlap_quads;
layout(constant_id = 3) const uint NODE_ROW = 4096u; // kernels::table_row

ivec2 row_texel(uint t) {
    return table_texel(t, NODE_ROW);
}

// fixed::FIXED_SLOTS and fixed::NO_NODE.
const uint MAX_SLOTS = 32u;
const uint NO_NODE = 0xffffffffu;
// cpu::INSIDE_FADE.
const float INSIDE_FADE = 0.25;

// The caps each lane has counted so far: direction and cos of the half-angle; occlusion and
// sin of the half-angle. In shared memory, each lane its own column (cap j of lane l at
// j * 32 + l: consecutive lanes, consecutive words): a private array indexed by a loop
// variable is a select ladder over all its entries on SIMD drivers (lavapipe), read ~500
// times per vertex here. No lane reads another's entries, so no barrier is needed.
shared vec4 s_cap[MAX_SLOTS * 32u];
shared vec2 s_occ_sin[MAX_SLOTS * 32u];

float table_lookup(float cos_t, float h) {
    vec2 uv = ao_table_coords(cos_t, h);
    float x = uv.x * float(pc.table_n_psi - 1u);
    float y = uv.y * float(pc.table_n_theta - 1u);
    uint i0 = min(uint(x), pc.table_n_psi - 2u);
    uint j0 = min(uint(y), pc.table_n_theta - 2u);
    float fx = x - float(i0);
    float fy = y - float(j0);
    vec4 q = imageLoad(table_quads, ivec2(int(i0), int(j0)));
    float a = q.x + (q.y - q.x) * fx;
    float b = q.z + (q.w - q.z) * fx;
    return a + (b - a) * fy;
}

// formula::overlap_coords.
vec3 overlap_coords(float cos_a1, float cos_a2, float cos_g) {
    float a1 = acos(clamp(cos_a1, 0.0, 1.0));
    float a2 = acos(clamp(cos_a2, 0.0, 1.0));
    float g = acos(clamp(cos_g, -1.0, 1.0));
    float large = max(a1, a2);
    float small = min(a1, a2);
    float width = max(2.0 * small, 1e-6);
    return vec3(clamp(large * (2.0 / AO_PI), 0.0, 1.0),
                clamp(small / max(large, 1e-6), 0.0, 1.0),
                clamp((g - (large - small)) / width, 0.0, 1.0));
}

// OverlapTable::lookup (trilinear).
float overlap_lookup(float cos_a1, float cos_a2, float cos_g) {
    vec3 c = overlap_coords(cos_a1, cos_a2, cos_g);
    uint n = pc.overlap_n;
    float last = float(n - 1u);
    float x = c.x * last;
    float y = c.y * last;
    float z = c.z * last;
    uint i0 = min(uint(x), n - 2u);
    uint j0 = min(uint(y), n - 2u);
    uint k0 = min(uint(z), n - 2u);
    float fx = x - float(i0);
    float fy = y - float(j0);
    float fz = z - float(k0);
    float p[2];
    for (uint q = 0u; q < 2u; ++q) {
        vec4 t = imageLoad(overlap_quads, ivec3(int(i0), int(j0), int(k0 + q)));
        float a = t.x + (t.y - t.x) * fx;
        float b = t.z + (t.w - t.z) * fx;
        p[q] = a + (b - a) * fy;
    }
    return p[0] + (p[1] - p[0]) * fz;
}

void main() {
    uint vi = gl_GlobalInvocationID.x;
    if (vi >= pc.vertex_count) return;
    vec3 p = pos.p[vi].xyz;
    vec3 n = nrm.n[vi].xyz;

    uint lane = gl_LocalInvocationID.x;
    uint count = 0u;
    float total = 0.0;
    uint tested = 0u;
    uint used = 0u;
    for (uint slot = 0u; slot < pc.slots; ++slot) {
        uint node = imageLoad(fixed_nodes, row_texel(slot * pc.vertex_count + vi)).x;
        if (node == NO_NODE) break;
        tested++;
        vec4 s = imageLoad(nodes, row_texel(2u * node));
        vec3 dv = s.xyz - p;
        float d = length(dv);
        if (!(d > s.w || CLAMP_INSIDE)) continue;
        float h = d / s.w;
        if (!CLAMP_INSIDE && h < 1.0 + INSIDE_FADE) h /= max((h - 1.0) / INSIDE_FADE, 1e-6);
        float cos_t = d > 0.0 ? dot(n, dv) / d : 1.0;
        vec3 wd = d > 0.0 ? dv / d : n;
        float occ = EXACT ? sphere_occlusion(cos_t, h) : table_lookup(cos_t, h);
        used++;
        if (occ <= 0.0) continue;
        float cos_a = sqrt(max(1.0 - 1.0 / max(h * h, 1.0), 0.0));
        float sin_a = 1.0 / max(h, 1.0);
        // Between the largest pairwise overlap and their sum (capped): the midpoint (cpu.rs).
        float largest = 0.0;
        float sum = 0.0;
        for (uint j = 0u; j < count; ++j) {
            // formula::pair_overlap: disjoint caps (g >= a + a_j) skip the lookup.
            vec4 cj = s_cap[j * 32u + lane];
            vec2 oj = s_occ_sin[j * 32u + lane];
            float cos_g = dot(wd, cj.xyz);
            float cos_sum = cos_a * cj.w - sin_a * oj.y;
            float o = 0.0;
            if (cos_g > cos_sum) o = overlap_lookup(cos_a, cj.w, cos_g) * min(occ, oj.x);
            largest = max(largest, o);
            sum += o;
        }
        float over = 0.5 * (largest + min(sum, occ));
        total += occ - over;
        s_cap[count * 32u + lane] = vec4(wd, cos_a);
        s_occ_sin[count * 32u + lane] = vec2(occ, sin_a);
        count++;
    }
    float visibility = clamp(1.0 - total, 0.0, 1.0);
    if (CORRECT) visibility = min(visibility * correction.c[vi], 1.0);
    ao.v[vi] = visibility;
    stats.tested_used[vi] = uvec2(tested, used);
}
