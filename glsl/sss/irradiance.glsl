#include <common/util.glsl>
// Texture-space irradiance (glsl/sss/irradiance*.comp). SSS_POSED: the texel's position and
// normal are computed here from its triangle and barycentrics (fixed by the UV layout) and this
// pose's vertex frames (what pass `sss pose texels` writes for a diagnostic readback), instead
// of read from the per-texel images. SSS_ENV: a per-vertex rgb irradiance (the caller's
// buffer `venv`, e.g. the environment shadowed by the character) is interpolated with the
// texel's barycentrics and added to the lights' E; the output is then rgb (`penv`, alpha -1
// where no surface) instead of the grey `pe`.
// Texture-space irradiance: E per texel from directional and point lights, E =
// sum_l strength_l max(n.l, 0) V_l, with the texel's own normal, position (point-light
// distance) and cosine, and the visibility V_l interpolated over the texel's triangle from
// the per-vertex shadow rays of pass `sss vertex light` (glsl/sss/vertex_light.comp): where
// the triangle's three corners agree, V is theirs (0 or 1); where they disagree (a shadow
// boundary crosses the triangle) and refine is on, the texel casts its own shadow ray through
// the BVH (the same traversal as the vertex pass), else V is interpolated with the texel
// centre's barycentrics. The texels' own rays are a second pass (SSS_RAYS, `sss irradiance
// rays`): the shading pass lists each texel that needs them with its lights (binding 17),
// and the ray pass, dispatched indirectly over that list, adds their light to its output.
// About 9% of the head's texels need rays, in runs that fill about half of an 8-texel
// segment: traced where they were found, half of each SIMD step's lanes idled through the
// BVH walks of the others; listed, the walks run on full steps. White lights: one grey E. Transmission (mode != 0):
// the per-vertex (rgb, thickness) interpolated. What this changes against a ray per texel is
// measured by `vkshade sss` (report.json `shadowing`): shadows smaller than a triangle that
// touch none of its corners are missed. Everything per texel is an image (lavapipe fetches a texel's four channels at
// once; a storage-buffer load at a per-lane index loops over the lanes for each component).
// The CPU twin is src/kernels/sss/cpu.rs.
#ifdef SSS_RAYS
layout(local_size_x = 64) in;
#else
layout(local_size_x = 8, local_size_y = 8) in;
#endif

layout(push_constant) uniform Push {
    uint size;     // texture is size x size
    uint lights;
    uint mode;     // transmission: 0 off, else on
    uint refine;   // 1: a shadow ray per texel where the corners disagree
    float bias;    // shadow-ray origin offset along the normal (mm)
    uint tiles;    // occupied row segments
} pc;

const uint VERTEX_ROW = 1024u;

#ifdef SSS_POSED
// Per texel: (triangle, w1 bits, w2 bits, flag bits), fixed by the UV layout; per triangle
// (BVH_ROW a row) the face normal and texel area, and per vertex v the frame (position mm,
// normal) at texels 2v, 2v + 1 (passes `sss pose triangles`, `sss pose vertices`).
layout(set = 0, binding = 12, rgba32ui) readonly uniform uimage2D source;
layout(set = 0, binding = 13, rgba32f) readonly uniform image2D trirec;
layout(set = 0, binding = 14, rgba32f) readonly uniform image2D vframes;
#else
layout(set = 0, binding = 0, rgba32f) readonly uniform image2D pos;     // xyz, flag
layout(set = 0, binding = 1, rgba32f) readonly uniform image2D nrm;     // xyz, area
#endif
// The texel's triangle corners (vertex indices) and barycentrics w1, w2 as 16-bit fractions
// of 2^16 in w (cpu::texel_corners_packed).
layout(set = 0, binding = 2, rgba32ui) readonly uniform uimage2D corners;
#include <sss/lights.glsl>
#include <sss/transmission.glsl>
#ifndef SSS_RAYS
layout(set = 0, binding = 4, r32ui) readonly uniform uimage2D vis;
layout(set = 0, binding = 5, rgba32f) readonly uniform image2D vtrans;
// Transmission: written only when mode != 0 (the kernel clears it when transmission is off;
// lavapipe stores a texel lane by lane, and a store per texel costs ~2.5 ms at 512^2).
layout(set = 0, binding = 7, rgba32f) writeonly uniform image2D trans;  // rgb, t
#endif
// The BVH as one table (row BVH_ROW; glsl/common/bvh.glsl): nodes 2 texels each, then
// triangles 3 each from texel TRI_BASE.
const uint BVH_ROW = 1024u;
layout(set = 0, binding = 8, rgba32ui) readonly uniform uimage2D nodes;
// The output: the grey E for the diffusion's gathers (glsl/sss/diffusion_grey.comp: one
// channel, the cheapest gather), E >= 0, -1 where no surface. The kernel reads the
// irradiance back from it (rgb = E, alpha 1; 0 where E < 0).
#ifdef SSS_ENV
// Per vertex of the posed mesh: rgb irradiance (radiometric, no 1/pi), the caller's buffer
// copied into an image (vertex v at (v % VERTEX_ROW, v / VERTEX_ROW); glsl/sss/vertex_env.comp).
#ifndef SSS_RAYS
layout(set = 0, binding = 15, rgba32f) readonly uniform image2D venv_texels;
#endif
// The output: rgb E, alpha 1 on the surface, -1 where no surface (the kernel clears it
// once; the diffusion's gathers read it: glsl/sss/diffusion_env.comp).
#ifdef SSS_RAYS
layout(set = 0, binding = 16, rgba32f) uniform image2D penv;
#else
layout(set = 0, binding = 16, rgba32f) writeonly uniform image2D penv;
#endif
#elif defined(SSS_RAYS)
layout(set = 0, binding = 10, r32f) uniform image2D pe;
#else
layout(set = 0, binding = 10, r32f) writeonly uniform image2D pe;
#endif
// The texels whose lights need their own shadow rays, appended by the shading pass in no
// set order: per listed texel (x | y << 16, a bit per light), room for every texel; and its
// head (ceil(count / 256), 1, 1, count), the ray pass's VkDispatchIndirectCommand of 64-lane
// workgroups (4 entries a lane) and the count (the kernel resets it to (0, 1, 1, 0) before
// each shading pass).
const uint RAY_PACKET = 4u; // list entries a lane of the ray pass takes (8: 5-8% slower)
#ifdef SSS_RAYS
layout(std430, set = 0, binding = 17) readonly buffer RayHead { uint head[4]; } ray_head;
layout(std430, set = 0, binding = 18) readonly buffer Rays { uvec2 job[]; } rays;
#else
layout(std430, set = 0, binding = 17) buffer RayHead { uint head[4]; } ray_head;
layout(std430, set = 0, binding = 18) writeonly buffer Rays { uvec2 job[]; } rays;
#endif
// The occupied 8x1 row segments of the atlas (x / 8 | y << 16, built once per mesh: the UV
// layout does not change when it is skinned): workgroup (x, y) shades segments
// 8 (y * TILE_ROW + x) + local y, a SIMD step of 8 lanes per segment; texels of empty
// segments are never touched (the kernel clears the outputs there once).
const uint TILE_ROW = 256u;
// SSS_LISTED: the segments of this frame's reach instead (SssKernel::set_reach), listed by
// pass `sss reach list` (glsl/sss/reach_list.comp) with their count in the list's head;
// workgroup (x, y) shades entries 8 (y * gx + x) + local y, gx the dispatch's width. The
// other segments keep what they held (the diffusion of the needed segments reads none).
#ifdef SSS_LISTED
layout(std430, set = 0, binding = 25) readonly buffer ReachList { uint head[4]; uint v[]; } reach_list;
#elif !defined(SSS_RAYS)
layout(std430, set = 0, binding = 11) readonly buffer Tiles { uint v[]; } tiles;
#endif

#include <common/bvh.glsl>

#ifdef SSS_POSED
vec3 vload(uint k) {
    return imageLoad(vframes, table_texel(k, BVH_ROW)).xyz;
}
#endif

ivec2 vertex_at(uint v) {
    return table_texel(v, VERTEX_ROW);
}

// A texel's source, the first load: posed, (triangle, s1, s2, flag) bits, fixed by the UV
// layout; else the per-texel image's (position, flag). Its flag (0: no surface, 0.5: gutter,
// 1: covered), and with its corners, its position (mm) and unit normal (`texel_frame`).
#ifdef SSS_POSED
#define TexelSource uvec4
uvec4 texel_source(ivec2 at) { return imageLoad(source, at); }
float source_flag(uvec4 src) { return uintBitsToFloat(src.w); }
// As glsl/sss/pose_texels.comp (the same arithmetic).
void texel_frame(ivec2 at, uvec4 src, uvec4 cr, out vec3 p, out vec3 n) {
    float s1 = uintBitsToFloat(src.y), s2 = uintBitsToFloat(src.z);
    float s0 = 1.0 - s1 - s2;
    p = vload(2u * cr.x) * s0 + vload(2u * cr.y) * s1 + vload(2u * cr.z) * s2;
    n = vload(2u * cr.x + 1u) * s0 + vload(2u * cr.y + 1u) * s1 + vload(2u * cr.z + 1u) * s2;
    float ln = length(n);
    n = ln > 0.0 ? n * (1.0 / ln) : imageLoad(trirec, table_texel(src.x, BVH_ROW)).xyz;
}
#else
#define TexelSource vec4
vec4 texel_source(ivec2 at) { return imageLoad(pos, at); }
float source_flag(vec4 src) { return src.w; }
void texel_frame(ivec2 at, vec4 src, uvec4 cr, out vec3 p, out vec3 n) {
    p = src.xyz;
    n = imageLoad(nrm, at).xyz;
}
#endif

#ifdef SSS_RAYS
// Pass `sss irradiance rays`: each lane takes RAY_PACKET consecutive entries of the list
// (neighbouring texels, mostly toward the same light: the shading pass appends a segment's
// lanes in order) and, for each light any of them needs, walks the BVH with their rays
// together (glsl/sss/packet.glsl). The light of the rays that escape is added to their
// texels' E.
#include <sss/packet.glsl>

void main() {
    uint first = gl_GlobalInvocationID.x * RAY_PACKET;
    uint listed = min(ray_head.head[3], uint(rays.job.length()));
    if (first >= listed) return;
    ivec2 at[RAY_PACKET];
    vec3 p[RAY_PACKET], n[RAY_PACKET];
    uint mask[RAY_PACKET];
    float e[RAY_PACKET];
    uint lights_needed = 0u;
    for (uint k = 0u; k < RAY_PACKET; k++) {
        // Past the list's end: the last entry again, with no lights.
        uvec2 job = rays.job[min(first + k, listed - 1u)];
        at[k] = ivec2(job.x & 0xffffu, job.x >> 16u);
        mask[k] = first + k < listed ? job.y : 0u;
        lights_needed |= mask[k];
        texel_frame(at[k], texel_source(at[k]), imageLoad(corners, at[k]), p[k], n[k]);
        e[k] = 0.0;
    }
    while (lights_needed != 0u) {
        uint l = uint(findLSB(lights_needed));
        lights_needed &= lights_needed - 1u;
        vec3 o[RAY_PACKET], d[RAY_PACKET];
        float tmax[RAY_PACKET], add[RAY_PACKET];
        uint live = 0u;
        for (uint k = 0u; k < RAY_PACKET; k++) {
            float strength;
            float c = light_at(l, p[k], n[k], d[k], tmax[k], strength);
            o[k] = p[k] + n[k] * pc.bias;
            add[k] = strength * c;
            live |= ((mask[k] >> l) & 1u) << k;
        }
        uint blocked = blocked_rays(o, d, tmax, live);
        for (uint k = 0u; k < RAY_PACKET; k++) {
            if ((((live & ~blocked) >> k) & 1u) != 0u) e[k] += add[k];
        }
    }
    for (uint k = 0u; k < RAY_PACKET; k++) {
        if (e[k] == 0.0) continue;
#ifdef SSS_ENV
        vec4 v = imageLoad(penv, at[k]);
        imageStore(penv, at[k], vec4(v.rgb + vec3(e[k]), v.a));
#else
        imageStore(pe, at[k], vec4(imageLoad(pe, at[k]).x + e[k]));
#endif
    }
}
#else
void main() {
#ifdef SSS_LISTED
    uint ti = 8u * (gl_WorkGroupID.y * gl_NumWorkGroups.x + gl_WorkGroupID.x) + gl_LocalInvocationID.y;
    if (ti >= reach_list.head[3]) return;
    uint tile = reach_list.v[ti];
#else
    uint ti = 8u * (gl_WorkGroupID.y * TILE_ROW + gl_WorkGroupID.x) + gl_LocalInvocationID.y;
    if (ti >= pc.tiles) return;
    uint tile = tiles.v[ti];
#endif
    uvec2 xy = uvec2((tile & 0xffffu) * 8u + gl_LocalInvocationID.x, tile >> 16u);
    if (xy.x >= pc.size || xy.y >= pc.size) return;
    ivec2 at = ivec2(xy);
    TexelSource src = texel_source(at);
    float flag = source_flag(src);
    if (flag == 0.0) {
        if (TRANSMISSION && pc.mode != 0u) imageStore(trans, at, vec4(0.0));
#ifdef SSS_ENV
        imageStore(penv, at, vec4(0.0, 0.0, 0.0, -1.0));
#else
        imageStore(pe, at, vec4(-1.0));
#endif
        return;
    }
    uvec4 cr = imageLoad(corners, at);
    vec3 p, n;
    texel_frame(at, src, cr, p, n);
    const float Q = 1.0 / 65536.0;
    float w1 = float(cr.w & 0xffffu) * Q, w2 = float(cr.w >> 16u) * Q;
    float w0 = 1.0 - w1 - w2;
    ivec2 a0 = vertex_at(cr.x), a1 = vertex_at(cr.y), a2 = vertex_at(cr.z);
    uint b0 = imageLoad(vis, a0).x, b1 = imageLoad(vis, a1).x, b2 = imageLoad(vis, a2).x;
    float e = 0.0;
    // Lights whose visibility is the texel's own shadow ray: listed for the ray pass.
    uint pending = 0u;
    for (uint l = 0u; l < pc.lights; l++) {
        vec3 dir;
        float tmax, strength;
        float c = light_at(l, p, n, dir, tmax, strength);
        if (c <= 0.0 || strength == 0.0) continue;
        uint c0 = (b0 >> l) & 1u, c1 = (b1 >> l) & 1u, c2 = (b2 >> l) & 1u;
        float v;
        if (c0 == c1 && c1 == c2) {
            v = float(c0);
        } else if (pc.refine != 0u && flag == 1.0) { // gutters (0.5) interpolate
            pending |= 1u << l;
            continue;
        } else {
            v = w0 * float(c0) + w1 * float(c1) + w2 * float(c2);
        }
        e += strength * c * v;
    }
    if (pending != 0u) {
        uint k = atomicAdd(ray_head.head[3], 1u);
        // The list has a slot for every texel of the atlas: k < its length always.
        if (k < uint(rays.job.length())) rays.job[k] = uvec2(xy.x | (xy.y << 16u), pending);
        // A workgroup of the ray pass takes 64 x RAY_PACKET entries.
        if (k % (64u * RAY_PACKET) == 0u) atomicAdd(ray_head.head[0], 1u);
    }
#ifdef SSS_ENV
    // The caller's per-vertex irradiance at the texel (rgb), added to the lights' E.
    vec3 env = w0 * imageLoad(venv_texels, a0).rgb + w1 * imageLoad(venv_texels, a1).rgb
        + w2 * imageLoad(venv_texels, a2).rgb;
    imageStore(penv, at, vec4(vec3(e) + env, 1.0));
#else
    imageStore(pe, at, vec4(e));
#endif
    if (TRANSMISSION && pc.mode != 0u) {
        vec4 tr = w0 * imageLoad(vtrans, a0) + w1 * imageLoad(vtrans, a1) + w2 * imageLoad(vtrans, a2);
        imageStore(trans, at, tr);
    }
}
#endif
