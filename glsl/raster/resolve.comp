#version 450
#extension GL_ARB_gpu_shader_int64 : require
// The resolve pass of the compute rasteriser: per pixel, the triangle the visibility pass
// kept is fetched again and the pixel's ray (through its centre) intersected with it
// (Moller-Trumbore: exact, perspective-correct barycentrics, clamped into the triangle as
// the CPU G-buffer does); position, normal, tangent, handedness and uv are interpolated and
// written as the G-buffer the BTF pass reads, three layers:
//   0: (position, s * (1 + part))   s = handedness (+-1); all 0 where nothing is covered
//      (layers 1 and 2 are then not written)
//   1: (normal, u * tile_scale)
//   2: (tangent, v * tile_scale)
// The normal faces the camera: where the interpolated normal faces away (a back face, or a
// front face at a silhouette) it is negated and the handedness with it, so the bitangent
// s * cross(n, t) stays along +v.
// Two modes (dims.z): 0: one invocation per pixel of the image; 1: one workgroup per 16 x 4
// tile of the tile list `raster tiles` wrote (dispatched indirectly over it: the tiles
// covered this frame and those covered only last frame, whose pixels become empty here).
layout(local_size_x = 16, local_size_y = 4) in;
#include <common/tiles.glsl>

layout(push_constant) uniform Push {
    vec4 eye;      // xyz: camera position; w: uv scale (tile repeats per unit of uv)
    vec4 forward;  // xyz: unit view axis
    vec4 right;    // xyz: camera right * tan(fov_y / 2) * aspect
    vec4 up;       // xyz: camera up * tan(fov_y / 2)
    uvec4 dims;    // width, height, mode
} pc;

layout(std430, set = 0, binding = 0) readonly buffer Positions { vec4 p[]; } pos;
layout(std430, set = 0, binding = 1) readonly buffer Normals { vec4 n[]; } nrm;
layout(std430, set = 0, binding = 2) readonly buffer Tangents { vec4 t[]; } tan;
layout(std430, set = 0, binding = 3) readonly buffer Uvs { vec2 uv[]; } uvs;
layout(std430, set = 0, binding = 4) readonly buffer Triangles { uvec4 t[]; } tris;
layout(std430, set = 0, binding = 5) readonly buffer Visibility { uint64_t key[]; } vis;
layout(set = 0, binding = 6, rgba32f) writeonly uniform image2DArray gbuffer;
layout(std430, set = 0, binding = 7) readonly buffer Tiles { uint head[4]; uint list[]; } tiles;

void store(ivec2 px, vec4 g0, vec4 g1, vec4 g2) {
    imageStore(gbuffer, ivec3(px, 0), g0);
    imageStore(gbuffer, ivec3(px, 1), g1);
    imageStore(gbuffer, ivec3(px, 2), g2);
}

void main() {
    uvec2 px = gl_GlobalInvocationID.xy;
    if (pc.dims.z != 0u) {
        uint t = tiles.list[gl_WorkGroupID.x];
        px = tile_pixel(t, gl_LocalInvocationID.xy);
    }
    if (any(greaterThanEqual(px, pc.dims.xy))) return;
    uint64_t key = vis.key[px.y * pc.dims.x + px.x];
    if (key == ~0ul) {
        // Only the tag says "empty" (layers 1 and 2 are left as they were: readers test the
        // tag first; lavapipe stores image texels one lane at a time).
        imageStore(gbuffer, ivec3(px, 0), vec4(0.0));
        return;
    }
    uvec4 t = tris.t[uint(key & 0xFFFFFFFFul)];
    vec3 a = pos.p[t.x].xyz, b = pos.p[t.y].xyz, c = pos.p[t.z].xyz;
    vec2 s = (vec2(px) + 0.5) / vec2(pc.dims.xy) * 2.0 - 1.0;
    vec3 d = normalize(pc.forward.xyz + pc.right.xyz * s.x - pc.up.xyz * s.y);
    vec3 e1 = b - a, e2 = c - a;
    vec3 pv = cross(d, e2);
    float det = dot(e1, pv);
    vec3 tv = pc.eye.xyz - a;
    float inv = det != 0.0 ? 1.0 / det : 0.0;
    float u = clamp(dot(tv, pv) * inv, 0.0, 1.0);
    vec3 qv = cross(tv, e1);
    float v = clamp(dot(d, qv) * inv, 0.0, 1.0 - u);
    float w0 = 1.0 - u - v;
    // The hit point (the clamped barycentrics keep it on the triangle).
    vec3 p = a * w0 + b * u + c * v;
    vec3 n = nrm.n[t.x].xyz * w0 + nrm.n[t.y].xyz * u + nrm.n[t.z].xyz * v;
    float len = length(n);
    n = len > 0.0 ? n / len : normalize(cross(e1, e2));
    vec4 tg = tan.t[t.x] * w0 + tan.t[t.y] * u + tan.t[t.z] * v;
    float hand = tg.w >= 0.0 ? 1.0 : -1.0;
    if (dot(n, d) > 0.0) {
        n = -n;
        hand = -hand;
    }
    // The tangent Gram-Schmidt-orthogonalised against the (final) normal; any perpendicular
    // where it vanishes (the BTF pass normalises it).
    vec3 tt = tg.xyz - n * dot(n, tg.xyz);
    if (dot(tt, tt) < 1e-12) tt = abs(n.x) < 0.9 ? cross(n, vec3(1.0, 0.0, 0.0)) : cross(n, vec3(0.0, 1.0, 0.0));
    tt = normalize(tt);
    vec2 uv = (uvs.uv[t.x] * w0 + uvs.uv[t.y] * u + uvs.uv[t.z] * v) * pc.eye.w;
    store(ivec2(px), vec4(p, hand * (1.0 + float(t.w))), vec4(n, uv.x), vec4(tt, uv.y));
}
