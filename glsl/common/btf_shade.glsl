// BTF shading over a G-buffer, included by btf/shade_rows.comp (BTF_MODE 1),
// btf/shade_layers.comp (BTF_MODE 0) and btf/shade_block.comp (BTF_MODE 2), over every
// pixel, and their `_pixels` twins (BTF_PIXELS) over the list of pass `btf pixels`: one
// pipeline per layout, each with only its own sampling code (lavapipe inlines the sampler
// per call site; five sites cost 3x one).
// Per pixel: the view and each light in the tangent frame, two lookups in the parabolic
// map (nearest texel: indices are never filtered), and 3 x 3 = 9 taps of the packed BTF,
// weighted and summed:
//   out = sum_lights E * sum_i sum_j wL_i wV_j BTF(uv; l_i, v_j).
// Layout "layers": the image of (light l, view v) is slice s = v * 81 + l, in array
// texture s / layers_per_array at layer s % layers_per_array; the tile repeats in uv
// (REPEAT). Layout "rows": layer v holds the 81 light images side by side, each with a
// wrapped gutter (1 texel; 4 for BC1) left and right, so bilinear filtering stays inside the
// image; REPEAT wraps v. Texels are sRGB: the sampler decodes to linear before filtering.
// Texture "block" (rows of blocks, see src/kernels/btf/block.rs): one RGBA32UI texel is a
// 4 x 4 block (two linear 11:11:10 endpoints, 16 4-bit indices); blocks overlap by one
// texel, so the bilinear footprint of every tap lies in one block: one texelFetch per tap,
// and the footprint's block, bit positions and weights are computed once per pixel.
//
// The G-buffer and the maps are textures read with texelFetch: lavapipe gathers texel
// fetches across lanes but loads from a storage buffer at a per-lane index one lane at a
// time (three vec4 storage-buffer loads per pixel cost as much as the 9 taps of `block`).
#extension GL_EXT_control_flow_attributes : require

const uint MAX_LIGHTS = 2u;
layout(push_constant) uniform Push {
    vec4 camera;                // xyz: camera position; w = 0: xyz is the direction towards
                                // an orthographic camera instead
    vec4 light_dir[MAX_LIGHTS]; // xyz: unit direction towards the light (world)
    vec4 light_rgb[MAX_LIGHTS]; // rgb: its strength
    uvec4 dims;                 // width, height, lights, layers per array
    uvec4 layout_info;          // x: gutter; y: tile width; z: layer width; w: tile height
    uvec4 parts;                // x: part mask (bit p: shade part p; all ones: every part,
                                // ids past 31 too); pixels of other parts keep what they hold
} pc;

#if BTF_MODE == 2
layout(set = 0, binding = 0) uniform utexture2DArray btf_blocks;
#else
layout(set = 0, binding = 0) uniform texture2DArray btf[4];
layout(set = 0, binding = 1) uniform sampler tile_sampler;   // linear, repeat
#endif
// RGBA32UI per texel: x = three sample indices (8 bits each), yzw = their weights (f32 bits).
layout(set = 0, binding = 2) uniform utexture2D dir_map;
// Layers 0, 1, 2: (position, tag), (normal, u), (tangent, v); tag = 0 where empty, else
// s * (1 + part), s = +-1 the frame's handedness (src/scene/gbuffer.rs).
layout(set = 0, binding = 4) uniform texture2DArray gbuffer;
layout(std430, set = 0, binding = 5) writeonly buffer Result { vec4 v[]; } result;
#include <common/btf_pixels.glsl>

#if BTF_MODE == 2
// The footprint of a pixel's uv, shared by its 9 taps: block, bit shifts of its 4 texels'
// indices (within z for rows 0-1, w for rows 2-3: `hi` says which) and bilinear weights.
struct Footprint {
    ivec2 block;
    uvec4 shift;
    bvec4 hi;
    vec4 weight;
};

Footprint footprint(vec2 uv) {
    vec2 size = vec2(pc.layout_info.y, pc.layout_info.w);
    vec2 xy = fract(uv) * size - 0.5;
    vec2 f = floor(xy);
    vec2 fr = xy - f;
    ivec2 xe = ivec2(f) + 1;   // 0 .. size: left/top texel + 1
    Footprint p;
    p.block = xe / 3;
    ivec2 o = xe - 3 * p.block;
    uint s0 = uint(16 * (o.y & 1) + 4 * o.x);
    uint s1 = uint(16 * ((o.y + 1) & 1) + 4 * o.x);
    p.shift = uvec4(s0, s0 + 4u, s1, s1 + 4u);
    p.hi = bvec4(o.y >= 2, o.y >= 2, o.y + 1 >= 2, o.y + 1 >= 2);
    p.weight = vec4((1.0 - fr.x) * (1.0 - fr.y), fr.x * (1.0 - fr.y),
                    (1.0 - fr.x) * fr.y, fr.x * fr.y);
    return p;
}

vec3 endpoint(uint e) {
    return vec3(e & 0x7FFu, (e >> 11u) & 0x7FFu, e >> 22u)
         * vec3(1.0 / 2047.0, 1.0 / 2047.0, 1.0 / 1023.0);
}

vec3 tap(uint view, uint light, Footprint p) {
    int blocks_x = int(pc.layout_info.z / 81u);
    uvec4 q = texelFetch(btf_blocks,
                         ivec3(p.block.x + int(light) * blocks_x, p.block.y, int(view)), 0);
    uvec4 word = uvec4(p.hi.x ? q.w : q.z, p.hi.y ? q.w : q.z,
                       p.hi.z ? q.w : q.z, p.hi.w ? q.w : q.z);
    vec4 idx = vec4((word >> p.shift) & 15u);
    vec3 e0 = endpoint(q.x);
    return e0 + (endpoint(q.y) - e0) * (dot(p.weight, idx) * (1.0 / 15.0));
}
#else
struct Footprint {
    vec2 uv;
};

Footprint footprint(vec2 uv) {
    return Footprint(uv);
}

vec3 tap(uint view, uint light, Footprint p) {
    vec2 uv = p.uv;
#if BTF_MODE == 1
        // Rows: image `light` of layer `view` starts at texel light * (w + 2 g) + g, with
        // g = layout_info.x wrapped columns each side (1 for RGBA8, 4 for BC1 blocks).
        float w = float(pc.layout_info.y);
        float g = float(pc.layout_info.x);
        float x = float(light) * (w + 2.0 * g) + g + fract(uv.x) * w;
        return textureLod(sampler2DArray(btf[0], tile_sampler),
                          vec3(x / float(pc.layout_info.z), uv.y, float(view)), 0.0).rgb;
#else
    uint slice = view * 81u + light;
    uint a = slice / pc.dims.w;
    vec3 c = vec3(uv, float(slice - a * pc.dims.w));
    if (a == 0u) return textureLod(sampler2DArray(btf[0], tile_sampler), c, 0.0).rgb;
    if (a == 1u) return textureLod(sampler2DArray(btf[1], tile_sampler), c, 0.0).rgb;
    if (a == 2u) return textureLod(sampler2DArray(btf[2], tile_sampler), c, 0.0).rgb;
    return textureLod(sampler2DArray(btf[3], tile_sampler), c, 0.0).rgb;
#endif
}
#endif

// Map texel of a tangent-space direction (z > 0): parabolic p = d.xy / (1 + d.z); its
// three sample indices and weights.
void lookup(vec3 d, out uvec3 index, out vec3 weight) {
    ivec2 n = textureSize(dir_map, 0);
    vec2 p = d.xy / (1.0 + d.z);
    ivec2 t = clamp(ivec2(floor((p + 1.0) * 0.5 * vec2(n))), ivec2(0), n - 1);
    uvec4 m = texelFetch(dir_map, t, 0);
    index = uvec3(m.x & 0xFFu, (m.x >> 8u) & 0xFFu, (m.x >> 16u) & 0xFFu);
    weight = uintBitsToFloat(m.yzw);
}

void main() {
    uvec2 px;
    if (!shaded_pixel(pc.dims.xy, px)) return;
    uint k = px.y * pc.dims.x + px.x;
    vec4 g0 = texelFetch(gbuffer, ivec3(px, 0), 0);
    if (abs(g0.w) < 0.5) {
        result.v[k] = vec4(0.0);
        return;
    }
    uint part = uint(abs(g0.w) + 0.5) - 1u;
    if (pc.parts.x != 0xFFFFFFFFu && (part >= 32u || (pc.parts.x & (1u << part)) == 0u)) return;
    vec4 g1 = texelFetch(gbuffer, ivec3(px, 1), 0);
    vec4 g2 = texelFetch(gbuffer, ivec3(px, 2), 0);
    vec3 n = normalize(g1.xyz);
    vec3 t = normalize(g2.xyz - n * dot(n, g2.xyz));
    vec3 b = (g0.w < 0.0 ? -1.0 : 1.0) * cross(n, t);   // handedness: the tag's sign
    Footprint fp = footprint(vec2(g1.w, g2.w));
    vec3 view = pc.camera.w == 0.0 ? pc.camera.xyz : normalize(pc.camera.xyz - g0.xyz);
    vec3 vt = vec3(dot(view, t), dot(view, b), dot(view, n));
    vec3 sum = vec3(0.0);
    if (vt.z > 0.0) {
        uvec3 iv;
        vec3 wv;
        lookup(vt, iv, wv);
#if BTF_MODE == 2 && defined(BTF_PIXELS)
        // Blocks over the pixel list (the character frame's cloth): both loops unrolled for
        // MAX_LIGHTS lights (a light past pc.dims.z has zero direction and strength, and
        // adds nothing). A block tap is one fetch and a few instructions, so its 18 copies
        // cost less than the loops' mask bookkeeping: `btf shade` in `bench frame` (two
        // lights), alternated runs: 6.0-6.6 -> 4.8-5.6 ms. Not over every pixel
        // (btf/shade_block.comp, `bench btf`'s one light): lavapipe runs the unused second
        // light masked, and that cost one light ~15% more (12.4-14.1 -> 14.7-15.7 ms).
        [[unroll]] for (uint i = 0u; i < MAX_LIGHTS; i++) {
#else
        for (uint i = 0u; i < min(pc.dims.z, MAX_LIGHTS); i++) {
#endif
            vec3 l = pc.light_dir[i].xyz;
            vec3 lt = vec3(dot(l, t), dot(l, b), dot(l, n));
            if (lt.z <= 0.0) continue;
            uvec3 il;
            vec3 wl;
            lookup(lt, il, wl);
            vec3 c = vec3(0.0);
            // One loop of 9 taps (a tap with zero weight, a virtual direction past 75 deg,
            // adds 0): lavapipe runs 8 pixels in lock step, so skipping a tap saves nothing
            // unless all 8 skip it, and one loop keeps one call site of the sampling code
            // (inlined per call site: unrolled, the sampled paths ran 3x slower; two nested
            // loops cost `block` 8% more). Blocks over the tile list unroll it (above).
#if BTF_MODE == 2 && defined(BTF_PIXELS)
            [[unroll]]
#endif
            for (int j = 0; j < 9; j++) {
                int a = j / 3;
                int e = j - 3 * a;
                c += (wv[a] * wl[e]) * tap(iv[a], il[e], fp);
            }
            sum += pc.light_rgb[i].rgb * c;
        }
    }
    result.v[k] = vec4(sum, 1.0);
}
