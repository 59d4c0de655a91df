// The character frame's last pass: one invocation per pixel of the screen G-buffer
// (compose/shade.comp), or per pixel of the rasteriser's listed tiles, the rest holding
// the background (pass `compose background`; COMPOSE_TILES: compose/shade_tiles.comp).
// - Skin pixels (triangles below the skin triangle count: the skin parts come first in the
//   character's mesh) look the texture-space diffusion up at the pixel's atlas uv (the
//   triangle's atlas corners interpolated with the pixel's barycentrics; bilinear over the
//   atlas's valid texels) and shade it with Fresnel transmission at exit,
//   L_d = (1 - F(n.v)) / pi * D (D: diffused irradiance; the entry transmission is in D),
//   plus a Kelemen/Szirmay-Kalos specular layer, f = rho_s * (P_H / pi) * F(h.v) / |l + v|^2
//   (P_H: Beckmann without 1/pi), for the directional lights (unshadowed: only the diffuse
//   irradiance carries the lights' shadows) and for every environment lobe through the warped-NDF SG (axis r = reflect(-v, n), sharpness
//   (2/m^2) / (4 n.v), amplitude 1/(pi m^2)), each lobe weighted by its per-vertex
//   visibility V_j interpolated to the pixel.
//   The diffuse exit is multiplied by the part's surface colour (below); the specular is not.
// - Cloth pixels take the BTF pass's radiance times the part's surface colour.
// - Surface colour of part p (the G-buffer tag's): scale_p times, where the part has a
//   texture, its linear colour at the pixel's mesh uv (the G-buffer's uv over the raster's uv
//   scale): bilinear between texel centres over the four texels decoded from sRGB, the
//   part's wrap modes at the borders (twin: scene::material::Texture::sample).
// - Background pixels take the background colour (evaluating every lobe per background
//   pixel cost more than the rest of the pass together on lavapipe).
// Then exposure, the ACES fit (Narkowicz) and sRGB encoding into an RGBA8 word per pixel;
// the linear HDR radiance is kept too. The CPU twin is kernels::compose::cpu::shade.
#extension GL_EXT_samplerless_texture_functions : require
layout(local_size_x = 16, local_size_y = 4) in;
#include <common/tiles.glsl>

layout(set = 0, binding = 0) uniform texture2DArray gbuffer;
layout(std430, set = 0, binding = 1) readonly buffer Keys { uvec2 k[]; } keys;
layout(std430, set = 0, binding = 2) readonly buffer Positions { vec4 p[]; } pos;
// Per skin triangle: vertex ids (xyz), then atlas uv of corners 0, 1 (one vec4) and 2.
layout(std430, set = 0, binding = 3) readonly buffer SkinTris { uvec4 v[]; } skin_tris;
layout(std430, set = 0, binding = 4) readonly buffer SkinUvs { vec4 uv[]; } skin_uvs;
layout(std430, set = 0, binding = 5) readonly buffer Diffuse { vec4 d[]; } diffuse;
layout(std430, set = 0, binding = 6) readonly buffer AtlasMask { float m[]; } mask;
layout(std430, set = 0, binding = 7) readonly buffer Cloth { vec4 c[]; } cloth;
layout(std430, set = 0, binding = 8) readonly buffer Lobes { vec4 l[]; } lobes;
layout(std430, set = 0, binding = 9) readonly buffer LobeVisibility { float v[]; } lobe_vis;
// Per part: (scale rgb as float bits, 0), (texel offset, width, height, wrap u | wrap v << 2).
layout(std430, set = 0, binding = 13) readonly buffer Surfaces { uvec4 s[]; } surfaces;
layout(std430, set = 0, binding = 14) readonly buffer SurfaceTexels { uint t[]; } texels;
#ifdef COMPOSE_TILES
// The rasteriser's list of covered 16 x 4 tiles (glsl/raster/tiles.comp), or one of the two
// parts pass `compose classify` splits it into (glsl/compose/classify.comp), dispatched
// indirectly: workgroup i shades tile list[i] (tile_entry(tx, ty), glsl/common/tiles.glsl);
// outside the rasteriser's list, the pixels hold the background (glsl/compose/background.comp).
layout(std430, set = 0, binding = 15) readonly buffer Tiles { uint head[4]; uint list[]; } tiles;
#endif
#include <compose/output.glsl>

const float PI = 3.14159265358979;

#include <compose/skin_uv.glsl>

float schlick(float f0, float c) {
    float x = 1.0 - clamp(c, 0.0, 1.0);
    float x2 = x * x;
    return f0 + (1.0 - f0) * x2 * x2 * x;
}

// <G1, G2> for unit axes: 2 pi mu1 mu2 e^(|r| - l1 - l2) (1 - e^(-2|r|)) / |r|, with the
// exponent in the cancellation-free form.
float sg_inner(vec3 p1, float l1, vec3 p2, float l2) {
    float r = length(l1 * p1 + l2 * p2);
    float e = -2.0 * l1 * l2 * (1.0 - dot(p1, p2)) / (r + l1 + l2);
    return 2.0 * PI * exp(e) * (1.0 - exp(-2.0 * r)) / max(r, 1e-6);
}

// Bilinear lookup of the diffusion over the atlas's valid texels.
vec3 atlas_lookup(vec2 uv, uint n) {
    vec2 t = uv * float(n) - 0.5;
    vec2 f0 = floor(t);
    vec2 f = t - f0;
    ivec2 i0 = ivec2(f0);
    vec3 sum = vec3(0.0);
    float wsum = 0.0;
    for (int k = 0; k < 4; k++) {
        ivec2 o = ivec2(k & 1, k >> 1);
        float w = (o.x == 1 ? f.x : 1.0 - f.x) * (o.y == 1 ? f.y : 1.0 - f.y);
        ivec2 c = clamp(i0 + o, ivec2(0), ivec2(int(n) - 1));
        uint i = uint(c.y) * n + uint(c.x);
        if (mask.m[i] > 0.0) {
            sum += w * diffuse.d[i].rgb;
            wsum += w;
        }
    }
    return wsum > 0.0 ? sum / wsum : vec3(0.0);
}

float srgb_decode(uint c) {
    float x = float(c) / 255.0;
    return x <= 0.04045 ? x / 12.92 : pow((x + 0.055) / 1.055, 2.4);
}

// Wrap modes: 0 repeat, 1 clamp to edge, 2 mirrored repeat. uv is clamped to [-512, 512]
// first, so i + 2048 n >= 0 and the remainder is taken on non-negative values (GLSL leaves %
// of a negative operand undefined).
int wrap(int i, int n, uint mode) {
    if (mode == 1u) return clamp(i, 0, n - 1);
    if (mode == 2u) {
        int k = int(uint(i + 2048 * n) % uint(2 * n));
        return k < n ? k : 2 * n - 1 - k;
    }
    return int(uint(i + 2048 * n) % uint(n));
}

// Whether any part has a base-colour texture (kernels::compose::pack::Surface::texture): a
// specialization constant, so that a character without one does not run the textured
// path, masked, at every pixel (lavapipe runs the code after an early return under a lane
// mask: four texel gathers, eight wraps, each a division or two by the texture's size, a
// lane at a time, and twelve sRGB decodes; `bench frame`, four alternated pairs on a loaded
// host: `compose shade` 4.7 / 4.9 / 3.4 / 3.2 -> 3.3 / 3.2 / 2.5 / 1.8 ms).
layout(constant_id = 0) const bool TEXTURED = true;

// Whether the pixels shaded may be skin: false in the pipeline over the tiles that pass
// `compose classify` found without a skin pixel (glsl/compose/classify.comp), so that the
// skin's path, which lavapipe runs masked at every pixel when present, compiles away there;
// also false for a character without skin. Where it is false no pixel may name a skin
// triangle (one would be shaded as cloth).
layout(constant_id = 1) const bool SKIN = true;

// Part `part`'s colour at a pixel whose G-buffer holds uv `gbuffer_uv` (the mesh's uv times
// the part's uv scale; the table holds its inverse).
vec3 surface_colour(uint part, vec2 gbuffer_uv, uint count) {
    if (part >= count) return vec3(1.0);
    uvec4 a = surfaces.s[2u * part];
    uvec4 t = surfaces.s[2u * part + 1u];
    vec3 scale = uintBitsToFloat(a.xyz);
    if (!TEXTURED || t.y == 0u) return scale;
    vec2 uv = gbuffer_uv * uintBitsToFloat(a.w);
    int w = int(t.y), h = int(t.z);
    uv = clamp(uv, vec2(-512.0), vec2(512.0));
    float tx = uv.x * float(w) - 0.5;
    float ty = uv.y * float(h) - 0.5;
    float fx0 = floor(tx), fy0 = floor(ty);
    float fx = tx - fx0, fy = ty - fy0;
    int ix = int(fx0), iy = int(fy0);
    vec3 sum = vec3(0.0);
    for (int k = 0; k < 4; k++) {
        int ox = k & 1, oy = k >> 1;
        float wgt = (ox == 1 ? fx : 1.0 - fx) * (oy == 1 ? fy : 1.0 - fy);
        int x = wrap(ix + ox, w, t.w & 3u);
        int y = wrap(iy + oy, h, t.w >> 2u);
        uint c = texels.t[t.x + uint(y * w + x)];
        sum += wgt * vec3(srgb_decode(c & 255u), srgb_decode((c >> 8u) & 255u),
                          srgb_decode((c >> 16u) & 255u));
    }
    return scale * sum;
}

void main() {
    Params P = params.p;
#ifdef COMPOSE_TILES
    uint tile = tiles.list[gl_WorkGroupID.x];
    uvec2 px = tile_pixel(tile, gl_LocalInvocationID.xy);
#else
    uvec2 px = gl_GlobalInvocationID.xy;
#endif
    if (any(greaterThanEqual(px, P.counts.xy))) return;
    uint idx = px.y * P.counts.x + px.x;
    vec3 d = pixel_ray(px, P.counts.xy, P.forward.xyz, P.right.xyz, P.up.xyz);
    uint lobes_n = P.counts.w;
    vec4 g0 = texelFetch(gbuffer, ivec3(px, 0), 0);
    vec3 radiance;
    if (g0.w == 0.0) {
        radiance = P.background.rgb;
    } else {
        uint tri = SKIN ? keys.k[idx].x : ~0u;
        uint part = uint(abs(g0.w) + 0.5) - 1u;
        vec2 gbuffer_uv = vec2(texelFetch(gbuffer, ivec3(px, 1), 0).w,
                               texelFetch(gbuffer, ivec3(px, 2), 0).w);
        vec3 colour = surface_colour(part, gbuffer_uv, P.atlas.w);
        if (SKIN && tri < P.atlas.y) {
            // Skin: the pixel's barycentrics on its triangle (as raster resolve finds them).
            uvec4 t = skin_tris.v[tri];
            vec3 bc = skin_barycentrics(pos.p[t.x].xyz, pos.p[t.y].xyz, pos.p[t.z].xyz, P.eye.xyz, d);
            float w0 = bc.x, u = bc.y, v = bc.z;
            vec2 uv = skin_atlas_uv(skin_uvs.uv[2u * tri], skin_uvs.uv[2u * tri + 1u].xy, bc);
            vec3 n = texelFetch(gbuffer, ivec3(px, 1), 0).xyz;
            vec3 view = -d;
            float nv = max(dot(n, view), 1e-4);
            float rho_s = P.skin.x, m = P.skin.y, f0 = P.skin.z;
            vec3 diffused = atlas_lookup(uv, P.atlas.x);
            radiance = (1.0 - schlick(f0, nv)) / PI * diffused * colour;
            // Specular: directional lights.
            vec3 spec = vec3(0.0);
            for (uint k = 0u; k < P.counts.z; k++) {
                vec3 l = P.light_dir[k].xyz;
                float nl = dot(n, l);
                if (nl <= 0.0) continue;
                vec3 hv = l + view;
                float hh = dot(hv, hv);
                if (hh < 1e-8) continue;
                vec3 h = hv * inversesqrt(hh);
                float nh = max(dot(n, h), 1e-4);
                float nh2 = nh * nh;
                float tan2 = (1.0 - nh2) / nh2;
                float ph = exp(-tan2 / (m * m)) / (m * m * nh2 * nh2);
                spec += P.light_rgb[k].rgb * (rho_s * ph / PI * schlick(f0, dot(h, view)) * nl / hh);
            }
            // Specular: environment lobes through the warped NDF.
            if (lobes_n > 0u) {
                vec3 r = reflect(-view, n);
                float nr = dot(n, r);
                vec3 hv = r + view;
                float hh = dot(hv, hv);
                if (nr > 0.0 && hh > 1e-8) {
                    float lam = (2.0 / (m * m)) / (4.0 * max(nv, 0.1));
                    float fr = schlick(f0, dot(hv * inversesqrt(hh), view));
                    float scale = rho_s * fr * nr / hh / (PI * m * m);
                    for (uint j = 0u; j < lobes_n; j++) {
                        vec4 ax = lobes.l[2u * j];
                        float vis = 1.0;
                        if (P.atlas.z == 1u) {
                            vis = lobe_vis.v[t.x * lobes_n + j] * w0
                                + lobe_vis.v[t.y * lobes_n + j] * u
                                + lobe_vis.v[t.z * lobes_n + j] * v;
                        }
                        spec += lobes.l[2u * j + 1u].rgb
                            * (scale * vis * sg_inner(r, lam, ax.xyz, ax.w));
                    }
                }
            }
            radiance += spec;
        } else {
            radiance = cloth.c[idx].rgb * colour;
        }
    }
    store_pixel(idx, radiance, g0.w == 0.0 ? 0.0 : 1.0, P.eye.w);
}
