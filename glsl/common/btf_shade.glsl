// BTF shading over a G-buffer, included by btf/shade_rows.comp (BTF_ROWS 1) and
// btf/shade_layers.comp (BTF_ROWS 0): one pipeline per layout, each with only its own
// sampling code (lavapipe inlines the sampler per call site; five sites cost 3x one).
// Per pixel: the view and each light in the tangent frame, two
// lookups in the parabolic index/weight maps (nearest texel: indices are never filtered),
// and 3 x 3 = 9 taps of the packed BTF, weighted and summed:
//   out = sum_lights E * sum_i sum_j wL_i wV_j BTF(uv; l_i, v_j).
// Layout "layers": the image of (light l, view v) is slice s = v * 81 + l, in array
// texture s / layers_per_array at layer s % layers_per_array; the tile repeats in uv
// (REPEAT). Layout "rows": layer v holds the 81 light images side by side, each with a
// wrapped gutter (1 texel; 4 for BC1) left and right, so bilinear filtering stays inside the image;
// REPEAT wraps v. Texels are sRGB: the sampler decodes to linear before filtering.
layout(local_size_x = 8, local_size_y = 8) in;

const uint MAX_LIGHTS = 2u;
layout(push_constant) uniform Push {
    vec4 camera;                // xyz: camera position; w = 0: xyz is the direction towards
                                // an orthographic camera instead
    vec4 light_dir[MAX_LIGHTS]; // xyz: unit direction towards the light (world)
    vec4 light_rgb[MAX_LIGHTS]; // rgb: its strength
    uvec4 dims;                 // width, height, lights, layers per array
    uvec4 layout_info;          // x: gutter; y: tile width; z: layer width (w unused)
} pc;

layout(set = 0, binding = 0) uniform texture2DArray btf[4];
layout(set = 0, binding = 1) uniform sampler tile_sampler;   // linear, repeat
layout(set = 0, binding = 2) uniform utexture2D index_map;   // RGBA8UI: 3 sample indices
layout(set = 0, binding = 3) uniform texture2D weight_map;   // RGBA32F: 3 weights
// Three vec4 per pixel: (position, valid), (normal, u), (tangent, v).
layout(std430, set = 0, binding = 4) readonly buffer GBuffer { vec4 g[]; } gbuffer;
layout(std430, set = 0, binding = 5) writeonly buffer Result { vec4 v[]; } result;

vec3 tap(uint view, uint light, vec2 uv) {
#if BTF_ROWS
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

// Map texel of a tangent-space direction (z > 0): parabolic p = d.xy / (1 + d.z).
ivec2 map_texel(vec3 d) {
    ivec2 n = textureSize(index_map, 0);
    vec2 p = d.xy / (1.0 + d.z);
    return clamp(ivec2(floor((p + 1.0) * 0.5 * vec2(n))), ivec2(0), n - 1);
}

void main() {
    uvec2 px = gl_GlobalInvocationID.xy;
    if (any(greaterThanEqual(px, pc.dims.xy))) return;
    uint k = px.y * pc.dims.x + px.x;
    vec4 g0 = gbuffer.g[3u * k];
    vec4 g1 = gbuffer.g[3u * k + 1u];
    vec4 g2 = gbuffer.g[3u * k + 2u];
    if (g0.w < 0.5) {
        result.v[k] = vec4(0.0);
        return;
    }
    vec3 n = normalize(g1.xyz);
    vec3 t = normalize(g2.xyz - n * dot(n, g2.xyz));
    vec3 b = cross(n, t);
    vec2 uv = vec2(g1.w, g2.w);
    vec3 view = pc.camera.w == 0.0 ? pc.camera.xyz : normalize(pc.camera.xyz - g0.xyz);
    vec3 vt = vec3(dot(view, t), dot(view, b), dot(view, n));
    vec3 sum = vec3(0.0);
    if (vt.z > 0.0) {
        ivec2 tv = map_texel(vt);
        uvec3 iv = texelFetch(index_map, tv, 0).xyz;
        vec3 wv = texelFetch(weight_map, tv, 0).xyz;
        for (uint i = 0u; i < min(pc.dims.z, MAX_LIGHTS); i++) {
            vec3 l = pc.light_dir[i].xyz;
            vec3 lt = vec3(dot(l, t), dot(l, b), dot(l, n));
            if (lt.z <= 0.0) continue;
            ivec2 tl = map_texel(lt);
            uvec3 il = texelFetch(index_map, tl, 0).xyz;
            vec3 wl = texelFetch(weight_map, tl, 0).xyz;
            vec3 c = vec3(0.0);
            // Zero weights (virtual directions past 75 deg) are skipped. The loops stay
            // loops: unrolled, the sampling code (inlined per call site on lavapipe) made
            // the pass 3x slower.
            for (int a = 0; a < 3; a++) {
                if (wv[a] == 0.0) continue;
                for (int e = 0; e < 3; e++) {
                    if (wl[e] == 0.0) continue;
                    c += (wv[a] * wl[e]) * tap(iv[a], il[e], uv);
                }
            }
            sum += pc.light_rgb[i].rgb * c;
        }
    }
    result.v[k] = vec4(sum, 1.0);
}
