// The texture-space diffusion (glsl/sss/diffusion.comp, glsl/sss/diffusion_grey.comp; the
// method is described in diffusion.comp). SSS_GREY: the gathers read the grey E from one
// single-channel image (`pe`, written by the irradiance pass for white lights), one load per
// sample; SSS_ENV: the rgb E and the surface flag from one rgba image (`penv`, written by the
// irradiance pass with a per-vertex irradiance added); otherwise the surface flag and rgb E
// from two images (any irradiance, e.g. a caller's upload). The arithmetic is the same (w * vec3(E)).
#extension GL_EXT_control_flow_attributes : require
layout(local_size_x = 8, local_size_y = 8) in;

layout(push_constant) uniform Push {
    uint size;
    uint samples;
    uint tiles;      // occupied row segments
} pc;


// Per texel, images (lavapipe fetches a texel's four channels at once; a storage-buffer load
// at a per-lane index loops over the lanes for each component).
#if defined(SSS_GREY)
// The grey E (written by glsl/sss/irradiance.comp), -1 where no surface: one channel, the
// cheapest gather.
layout(set = 0, binding = 0, r32f) readonly uniform image2D pe;
#elif defined(SSS_ENV)
// The rgb E (written by glsl/sss/irradiance_env.comp, irradiance_posed_env.comp), alpha -1
// where no surface: one rgba gather.
layout(set = 0, binding = 0, rgba32f) readonly uniform image2D penv;
#else
layout(set = 0, binding = 0, rgba32f) readonly uniform image2D pos;   // xyz, flag
layout(set = 0, binding = 4, rgba32f) readonly uniform image2D irr;
#endif
// Per texel: its triangle, the barycentrics w1, w2 of its centre (float bits), and its contact
// entries (first << 5 | count) (src/kernels/sss/walk.rs, contact.rs).
layout(set = 0, binding = 1, rgba32ui) readonly uniform uimage2D start;
// Per triangle its walk record (binding 2, `walk`: glsl/sss/walk_record.glsl).
#include <sss/walk_record.glsl>
// Contact entries, WALK_ROW a row: (source texel, f_r, f_g, f_b bits).
layout(set = 0, binding = 3, rgba32ui) readonly uniform uimage2D contact;
// The patterns (cpu::sample_pattern) of the skin regions (src/kernels/sss/regions.rs; one for
// a single profile), region r's in row 2r, one texel per sample: (ux, uy, w_r, w_g), and
// w_b = 3 - w_r - w_g (the MIS weights sum to 3); row 2r + 1: texel 0 the region's scale
// per channel R_tot (the untruncated total), texel 1 the sum of each channel's weights over
// its pattern (pack::Pattern::texels). A texel diffuses with its triangle's region's (the
// exit point's profile). An image: lavapipe loads a uniform buffer at the loop index lane by
// lane, component by component. With the pattern as constants (UNIFORM_SAMPLES, below) only
// row 1 is read here.
layout(set = 0, binding = 5, rgba32f) readonly uniform image2D seq;
// With one region and at most MAX_UNIFORM_SAMPLES samples (SssKernel sets them; 0
// otherwise): the sample count, and the pattern is region 0's row as specialization
// constants, read in a loop of that fixed count, unrolled. The pattern's entries are then
// constants compiled into the loop instead of an image gather at each lane's row for every
// sample (`bench frame`, fastest of 4 alternated runs, 32 samples: 3.07 -> 2.17 ms; from a
// uniform buffer at the unrolled loop's constant offsets, 2.82: the constants folded into the
// arithmetic save more than the gather). Sample s is (PAT_Xs, PAT_Ys, PAT_Zs, PAT_Ws), constant_id 32 + 4 s + component
// (kernels::sss::pack::Pattern::constants).
layout(constant_id = 19) const uint UNIFORM_SAMPLES = 0u;
const uint MAX_UNIFORM_SAMPLES = 32u; // pack::MAX_UNIFORM_SAMPLES
#define PATTERN_SAMPLE(s) \
    layout(constant_id = 32 + 4 * s) const float PAT_X##s = 0.0; \
    layout(constant_id = 33 + 4 * s) const float PAT_Y##s = 0.0; \
    layout(constant_id = 34 + 4 * s) const float PAT_Z##s = 0.0; \
    layout(constant_id = 35 + 4 * s) const float PAT_W##s = 0.0;
PATTERN_SAMPLE(0) PATTERN_SAMPLE(1) PATTERN_SAMPLE(2) PATTERN_SAMPLE(3) PATTERN_SAMPLE(4) PATTERN_SAMPLE(5)
PATTERN_SAMPLE(6) PATTERN_SAMPLE(7) PATTERN_SAMPLE(8) PATTERN_SAMPLE(9) PATTERN_SAMPLE(10) PATTERN_SAMPLE(11)
PATTERN_SAMPLE(12) PATTERN_SAMPLE(13) PATTERN_SAMPLE(14) PATTERN_SAMPLE(15) PATTERN_SAMPLE(16) PATTERN_SAMPLE(17)
PATTERN_SAMPLE(18) PATTERN_SAMPLE(19) PATTERN_SAMPLE(20) PATTERN_SAMPLE(21) PATTERN_SAMPLE(22) PATTERN_SAMPLE(23)
PATTERN_SAMPLE(24) PATTERN_SAMPLE(25) PATTERN_SAMPLE(26) PATTERN_SAMPLE(27) PATTERN_SAMPLE(28) PATTERN_SAMPLE(29)
PATTERN_SAMPLE(30) PATTERN_SAMPLE(31)
#define PAT(s) vec4(PAT_X##s, PAT_Y##s, PAT_Z##s, PAT_W##s)
// Entry s of that pattern: a select per entry, folded to the constant itself where s is a
// constant (the unrolled loop's).
vec4 pattern_entry(uint s) {
    vec4 q = vec4(0.0);
#define PAT_CASE(k) if (s == uint(k)) q = PAT(k);
    PAT_CASE(0) PAT_CASE(1) PAT_CASE(2) PAT_CASE(3) PAT_CASE(4) PAT_CASE(5) PAT_CASE(6) PAT_CASE(7)
    PAT_CASE(8) PAT_CASE(9) PAT_CASE(10) PAT_CASE(11) PAT_CASE(12) PAT_CASE(13) PAT_CASE(14) PAT_CASE(15)
    PAT_CASE(16) PAT_CASE(17) PAT_CASE(18) PAT_CASE(19) PAT_CASE(20) PAT_CASE(21) PAT_CASE(22) PAT_CASE(23)
    PAT_CASE(24) PAT_CASE(25) PAT_CASE(26) PAT_CASE(27) PAT_CASE(28) PAT_CASE(29) PAT_CASE(30) PAT_CASE(31)
    return q;
}
layout(std430, set = 0, binding = 6) writeonly buffer Diffuse { vec4 v[]; } diffuse;
// The occupied 8x1 row segments of the atlas (x / 8 | y << 16, built once per mesh: the UV
// layout does not change when it is skinned): workgroup (x, y) shades segments
// 8 (y * TILE_ROW + x) + local y, a SIMD step of 8 lanes per segment; texels of empty
// segments are never touched (the kernel clears the outputs there once).
// SSS_LISTED: the segments a caller needs this frame instead (e.g. those the character
// frame's compose pass reads: glsl/compose/need.comp), listed by pass `sss needed list`
// (glsl/sss/needed_list.comp) with their count in the list's head; workgroup (x, y) shades
// list entries 8 (y * gx + x) + local y, gx the dispatch's width. The other segments keep
// what the output held.
const uint TILE_ROW = 256u;
#ifdef SSS_LISTED
layout(std430, set = 0, binding = 20) readonly buffer NeededList { uint head[4]; uint v[]; } needed_list;
#else
layout(std430, set = 0, binding = 7) readonly buffer Tiles { uint v[]; } tiles;
#endif

const float TAU = 6.28318530718;
const uint MAX_REGIONS = 8u; // regions::MAX_REGIONS

uint pcg(uint v) {
    uint state = v * 747796405u + 2891336453u;
    uint word = ((state >> ((state >> 28u) + 4u)) ^ state) * 277803737u;
    return (word >> 22u) ^ word;
}

// E at texel j (rgb); false where no surface.
bool source(ivec2 j, out vec3 e) {
#if defined(SSS_GREY)
    float ej = imageLoad(pe, j).x;
    e = vec3(ej);
    return ej >= 0.0;
#elif defined(SSS_ENV)
    vec4 ej = imageLoad(penv, j);
    e = ej.rgb;
    return ej.w >= 0.0;
#else
    vec4 pj = imageLoad(pos, j);
    e = imageLoad(irr, j).rgb;
    return pj.w != 0.0;
#endif
}

// What a texel's samples share (main): the pattern's rotation folded into the barycentric
// rates (rates: a, b, c, d of main) and the atlas map (uvt, mx, my), the texel's
// barycentrics (w0, w1, w2), and its triangle's edge kinds and crossing maps (v*, s*).
struct TexelSampler {
    vec4 rates;
    vec3 w;
    vec2 uvt, mx, my;
    uint kinds;
    vec4 v0, v1, v2;
    vec2 s0, s1, s2;
};

// One sample (pattern entry q: offset ux, uy and the weights w_r, w_g) into the texel's sums:
// it counts (sum), leaves (lost_w, lost), or counts as dark. Branch-free (lavapipe runs both
// sides of a divergent branch with masks, and a `continue` in one costs mask bookkeeping
// besides): both landings are computed, the right one selected, and every sample gathers (at
// texel 0 when it has nowhere to land). The CPU twin is walk::TexelSampler::land.
void diffusion_sample(vec4 q, TexelSampler sm, inout vec3 sum, inout vec3 lost_w, inout uint lost) {
    float w0 = sm.w.x, w1 = sm.w.y, w2 = sm.w.z;
    float nf = float(pc.size);
    vec3 w = vec3(q.z, q.w, 3.0 - q.z - q.w);
    float d2 = sm.rates.x * q.x + sm.rates.y * q.y;
    float d1 = sm.rates.z * q.x + sm.rates.w * q.y;
    float b1 = w1 + d1, b2 = w2 + d2;
    float bz = 1.0 - b1 - b2;
    // In the triangle: its own map.
    vec2 uv_in = sm.uvt + sm.mx * q.x + sm.my * q.y;
    // Leaving it: through the edge it leaves by, the first whose barycentric reaches 0
    // along the way. Barycentrics are linear along the offset, so that edge is one the
    // end point lies beyond (b_k < 0); of two such, edge i comes first when
    // w_i / -d_i < w_j / -d_j, i.e. w_i d_j > w_j d_i (no division).
    float d0 = -(d1 + d2);
    bool e0 = bz < 0.0 && (b1 >= 0.0 || w0 * d1 > w1 * d0) && (b2 >= 0.0 || w0 * d2 > w2 * d0);
    bool e1 = !e0 && b1 < 0.0 && (b2 >= 0.0 || w1 * d2 > w2 * d1);
    uint exit = e0 ? 0u : (e1 ? 1u : 2u);
    bool inside = min(bz, min(b1, b2)) >= 0.0;
    uint kind = inside ? EDGE_SHARED : (sm.kinds >> (2u * exit)) & 3u;
    vec4 m = e0 ? sm.v0 : (e1 ? sm.v1 : sm.v2);
    vec2 t = e0 ? sm.s0 : (e1 ? sm.s1 : sm.s2);
    vec2 uv_x = vec2(t.x + m.x * b1 + m.y * b2, t.y + m.z * b1 + m.w * b2);
    vec2 uv = inside ? uv_in : uv_x;
    float fx = floor(uv.x + 0.5), fy = floor(uv.y + 0.5);
    // (written so that NaN and infinities fail it)
    bool within = fx >= 0.0 && fy >= 0.0 && fx < nf && fy < nf;
    vec3 ej;
    bool surface = source(within ? ivec2(fx, fy) : ivec2(0), ej);
    // Off the surface past an open border: dark, counted. Across a non-manifold edge,
    // outside the texture or onto no surface: lost.
    bool open = kind == EDGE_OPEN;
    bool counts = kind == EDGE_SHARED && within && surface;
    bool gone = !open && !counts;
    sum += counts ? w * ej : vec3(0.0);
    lost_w += gone ? w : vec3(0.0);
    lost += gone ? 1u : 0u;
}

void main() {
#ifdef SSS_LISTED
    uint ti = 8u * (gl_WorkGroupID.y * gl_NumWorkGroups.x + gl_WorkGroupID.x) + gl_LocalInvocationID.y;
    if (ti >= needed_list.head[3]) return;
    uint tile = needed_list.v[ti];
#else
    uint ti = 8u * (gl_WorkGroupID.y * TILE_ROW + gl_WorkGroupID.x) + gl_LocalInvocationID.y;
    if (ti >= pc.tiles) return;
    uint tile = tiles.v[ti];
#endif
    uvec2 xy = uvec2((tile & 0xffffu) * 8u + gl_LocalInvocationID.x, tile >> 16u);
    if (xy.x >= pc.size || xy.y >= pc.size) return;
    uint i = xy.y * pc.size + xy.x;
    ivec2 at = ivec2(xy);
    vec3 eo;
    if (!source(at, eo)) {
        diffuse.v[i] = vec4(0.0);
        return;
    }
    uvec4 st = imageLoad(start, at);
    uint tri0 = st.x;
    float w1 = uintBitsToFloat(st.y), w2 = uintBitsToFloat(st.z);
    float w0 = 1.0 - w1 - w2;
    // The triangle's record: its frame (for the barycentric rates of an offset), edge kinds,
    // UV map and the three crossing maps (src/kernels/sss/walk.rs), loaded once per texel.
    uvec4 ra = record(tri0, 0u);
    uvec4 rb = record(tri0, 1u);
    uvec4 rc = record(tri0, 2u);
    vec3 sh = uintBitsToFloat(ra.xyz); // 1 / l1, x2, 1 / y2
    uint kinds = ra.w;
    vec2 uv0 = uintBitsToFloat(rb.xy), du1 = uintBitsToFloat(rb.zw), du2 = uintBitsToFloat(rc.xy);
    vec4 v0 = uintBitsToFloat(record(tri0, 3u)), v1 = uintBitsToFloat(record(tri0, 5u));
    vec4 v2 = uintBitsToFloat(record(tri0, 7u));
    vec2 s0 = uintBitsToFloat(record(tri0, 4u).xy), s1 = uintBitsToFloat(record(tri0, 6u).xy);
    vec2 s2 = uintBitsToFloat(record(tri0, 8u).xy);
    // The triangle's skin region (pack::region_records) and its profile's rows.
    // (clamped to the image, which holds two rows per region the kernel was made with)
    int row = 2 * min(int(min(rc.z, MAX_REGIONS - 1u)), imageSize(seq).y / 2 - 1);
    vec3 k3 = imageLoad(seq, ivec2(0, row + 1)).rgb;
    vec3 total = imageLoad(seq, ivec2(1, row + 1)).rgb;
    // The texel's rotation of the shared pattern, folded into the rates and the atlas map
    // (walk::TexelSampler): per sample, d2 = a ux + b uy, d1 = c ux + d uy, and inside the
    // triangle uv = uvt + ux * mx + uy * my.
    float phi0 = TAU * (float(pcg(i) >> 8u) / 16777216.0);
    float cs = cos(phi0), sn = sin(phi0);
    float ra_ = sn * sh.z;
    float rb_ = cs * sh.z;
    float rc_ = (cs - sh.y * ra_) * sh.x;
    float rd_ = (-sn - sh.y * rb_) * sh.x;
    vec2 uvt = uv0 + du1 * w1 + du2 * w2;
    vec2 mx = du1 * rc_ + du2 * ra_;
    vec2 my = du1 * rd_ + du2 * rb_;
    // Off the surface (past an open border): no light, the sample counts. Lost (a
    // non-manifold edge, outside the texture, no surface there): it leaves the sum and the
    // others renormalise (rare: their weights are subtracted from the pattern's total).
    vec3 sum = vec3(0.0), lost_w = vec3(0.0);
    uint lost = 0u;
    TexelSampler sm = TexelSampler(vec4(ra_, rb_, rc_, rd_), vec3(w0, w1, w2), uvt, mx, my, kinds,
                                   v0, v1, v2, s0, s1, s2);
    if (UNIFORM_SAMPLES != 0u) {
        [[unroll]] for (uint s = 0u; s < min(UNIFORM_SAMPLES, MAX_UNIFORM_SAMPLES); s++) {
            diffusion_sample(pattern_entry(s), sm, sum, lost_w, lost);
        }
    } else {
        for (uint s = 0u; s < pc.samples; s++) {
            diffusion_sample(imageLoad(seq, ivec2(s, row)), sm, sum, lost_w, lost);
        }
    }
    vec3 wsum = total - lost_w;
    // (every sample lost, rare: the texel's own E)
    vec3 own = vec3(
        wsum.r > 0.0 ? sum.r / wsum.r : eo.r,
        wsum.g > 0.0 ? sum.g / wsum.g : eo.g,
        wsum.b > 0.0 ? sum.b / wsum.b : eo.b);
    // Contact: light from other pieces of the mesh within reach (src/kernels/sss/contact.rs).
    vec3 touch = vec3(0.0);
    uint first = st.w >> 5u, count = st.w & 31u;
    for (uint c = 0u; c < count; c++) {
        uint ci = first + c;
        uvec4 en = imageLoad(contact, ivec2(ci % WALK_ROW, ci / WALK_ROW));
        vec3 ej;
        if (source(ivec2(en.x % pc.size, en.x / pc.size), ej)) {
            touch += uintBitsToFloat(en.yzw) * ej;
        }
    }
    diffuse.v[i] = vec4(k3 * own + touch, float(pc.samples - lost) / float(pc.samples));
}
