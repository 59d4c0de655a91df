// The texture-space diffusion (glsl/sss/diffusion.comp, glsl/sss/diffusion_grey.comp).
// SSS_GREY: the gathers read position and a grey E from one image (`pe`, written by the
// irradiance pass for white lights), one texel load per sample instead of two (lavapipe runs
// a per-lane load one lane at a time); otherwise position and rgb E from two images (any
// irradiance, e.g. a caller's upload). The arithmetic is the same (w * vec3(E)).
layout(local_size_x = 8, local_size_y = 8) in;

layout(push_constant) uniform Push {
    vec4 k;          // K(R) per channel (rgb)
    uint size;
    uint samples;
    float seam_rel;
    float seam_texels;
    uint tiles;      // occupied row segments
} pc;

const uint MAX_SAMPLES = 4096u;

// Per texel, images (lavapipe fetches a texel's four channels at once; a storage-buffer load
// at a per-lane index loops over the lanes for each component).
#ifdef SSS_GREY
// Position and E in one texel (written by glsl/sss/irradiance.comp): xyz, w = E or -1 where
// no surface.
layout(set = 0, binding = 0, rgba32f) readonly uniform image2D pe;
#else
layout(set = 0, binding = 0, rgba32f) readonly uniform image2D pos;   // xyz, flag
layout(set = 0, binding = 4, rgba32f) readonly uniform image2D irr;
#endif
layout(set = 0, binding = 1, rgba32f) readonly uniform image2D nrm;   // xyz, area
layout(set = 0, binding = 2, rgba32f) readonly uniform image2D dpdu;
layout(set = 0, binding = 3, rgba32f) readonly uniform image2D dpdv;
layout(std140, set = 0, binding = 5) uniform Seq { vec4 v[MAX_SAMPLES]; } seq; // r, w_rgb
layout(std430, set = 0, binding = 6) writeonly buffer Diffuse { vec4 v[]; } diffuse;
// The occupied 8x1 row segments of the atlas (x / 8 | y << 16, built once per mesh: the UV
// layout does not change when it is skinned): workgroup (x, y) shades segments
// 8 (y * TILE_ROW + x) + local y, a SIMD step of 8 lanes per segment; texels of empty
// segments are never touched (the kernel clears the outputs there once).
const uint TILE_ROW = 256u;
layout(std430, set = 0, binding = 7) readonly buffer Tiles { uint v[]; } tiles;

const float TAU = 6.28318530718;

uint pcg(uint v) {
    uint state = v * 747796405u + 2891336453u;
    uint word = ((state >> ((state >> 28u) + 4u)) ^ state) * 277803737u;
    return (word >> 22u) ^ word;
}

void main() {
    uint ti = 8u * (gl_WorkGroupID.y * TILE_ROW + gl_WorkGroupID.x) + gl_LocalInvocationID.y;
    if (ti >= pc.tiles) return;
    uint tile = tiles.v[ti];
    uvec2 xy = uvec2((tile & 0xffffu) * 8u + gl_LocalInvocationID.x, tile >> 16u);
    if (xy.x >= pc.size || xy.y >= pc.size) return;
    float nf = float(pc.size);
    uint i = xy.y * pc.size + xy.x;
    ivec2 at = ivec2(xy);
#ifdef SSS_GREY
    vec4 p4 = imageLoad(pe, at);
    if (p4.w < 0.0) {
        diffuse.v[i] = vec4(0.0);
        return;
    }
    vec3 eo = vec3(p4.w);
#else
    vec4 p4 = imageLoad(pos, at);
    if (p4.w == 0.0) {
        diffuse.v[i] = vec4(0.0);
        return;
    }
    vec3 eo = imageLoad(irr, at).rgb;
#endif
    vec3 po = p4.xyz;
    vec3 a = imageLoad(dpdu, at).xyz;
    vec3 b = imageLoad(dpdv, at).xyz;
    vec3 nn = imageLoad(nrm, at).xyz;
    vec3 t1 = a - nn * dot(nn, a);
    float t1l = length(t1);
    t1 = t1l > 0.0 ? t1 / t1l : vec3(0.0);
    vec3 t2 = cross(nn, t1);
    float aa = dot(a, a), ab = dot(a, b), bb = dot(b, b);
    float det = aa * bb - ab * ab;
    if (!(det > 1e-20 * aa * bb) || t1l == 0.0) {
        diffuse.v[i] = vec4(pc.k.rgb * eo, 0.0);
        return;
    }
    float r00 = dot(a, t1), r01 = dot(a, t2), r10 = dot(b, t1), r11 = dot(b, t2);
    float m00 = (bb * r00 - ab * r10) / det;
    float m01 = (bb * r01 - ab * r11) / det;
    float m10 = (-ab * r00 + aa * r10) / det;
    float m11 = (-ab * r01 + aa * r11) / det;
    float texel_mm = sqrt(length(cross(a, b))) / nf;
    float tol = pc.seam_texels * texel_mm;
    float x = float(xy.x), y = float(xy.y);
    // The texel's rotation of the shared pattern.
    float phi0 = TAU * (float(pcg(i) >> 8u) / 16777216.0);
    vec2 dir = vec2(cos(phi0), sin(phi0));
    const vec2 STEP = vec2(-0.73736883, -0.67549035); // (cos, sin) of 2 pi 0.618034
    vec3 sum = vec3(0.0), wsum = vec3(0.0);
    uint acc = 0u;
    for (uint s = 0u; s < pc.samples; s++) {
        vec4 q = seq.v[s];
        float r = q.x;
        float cs = dir.x * r, sn = dir.y * r;
        dir = vec2(dir.x * STEP.x - dir.y * STEP.y, dir.x * STEP.y + dir.y * STEP.x);
        float tx = x + (m00 * cs + m01 * sn) * nf;
        float ty = y + (m10 * cs + m11 * sn) * nf;
        float fx = floor(tx + 0.5), fy = floor(ty + 0.5);
        if (isnan(tx) || isnan(ty) || isinf(tx) || isinf(ty) || fx < 0.0 || fy < 0.0
            || fx >= nf || fy >= nf) continue;
        ivec2 j = ivec2(fx, fy);
#ifdef SSS_GREY
        vec4 pj = imageLoad(pe, j);
        if (pj.w < 0.0) continue;
#else
        vec4 pj = imageLoad(pos, j);
        if (pj.w == 0.0) continue;
#endif
        float d = length(pj.xyz - po);
        if (abs(d - r) <= pc.seam_rel * r + tol) {
            vec3 w = q.yzw;
#ifdef SSS_GREY
            sum += w * vec3(pj.w);
#else
            sum += w * imageLoad(irr, j).rgb;
#endif
            wsum += w;
            acc++;
        }
    }
    vec3 k3 = pc.k.rgb;
    vec3 outv = vec3(
        wsum.r > 0.0 ? k3.r * (sum.r / wsum.r) : k3.r * eo.r,
        wsum.g > 0.0 ? k3.g * (sum.g / wsum.g) : k3.g * eo.g,
        wsum.b > 0.0 ? k3.b * (sum.b / wsum.b) : k3.b * eo.b);
    diffuse.v[i] = vec4(outv, float(acc) / float(pc.samples));
}
