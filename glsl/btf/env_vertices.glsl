// `btf env vertices`: the cloth's light factors per vertex (bi-scale radiance transfer's
// per-vertex light factor): for each listed vertex, L_k = sum_j (V_j a_j / pi) Q_jk over the
// lobes `btf env basis` does not look up per pixel, in the
// vertex's own tangent frame (its posed normal, its tangent Gram-Schmidt-orthogonalised
// against it as the rasteriser's resolve does, the bitangent hand * n x t), once as the
// front face sees it and once as the back face does (normal negated). `btf env basis`
// (mode 3) interpolates them at each pixel with the barycentrics of its triangle instead
// of fetching every lobe's table per pixel. Twin: kernels::btf::basis::BasisData::
// vertex_light.
layout(local_size_x = 64) in;

layout(push_constant) uniform Push {
    uint count;        // listed vertices
    uint lobes;        // J
    uint vertex_count; // of the pose
    uint lobe_count;   // entries of `vlobes`
} pc;

layout(set = 0, binding = 0) uniform texture2DArray table;
layout(set = 0, binding = 1) uniform sampler table_sampler;  // linear, clamp to edge
// Two vec4 per lobe: (axis xyz world, sharpness), (amplitude rgb, 0).
layout(std430, set = 0, binding = 2) readonly buffer Lobes { vec4 v[]; } lobes;
layout(std430, set = 0, binding = 3) readonly buffer Normals { vec4 n[]; } nrm;
layout(std430, set = 0, binding = 4) readonly buffer Tangents { vec4 t[]; } tan;
layout(std430, set = 0, binding = 5) readonly buffer VertexVisibility { float v[]; } vertex_vis;
#ifdef ENV_VERTICES_LISTED
// A list written on the GPU this frame (e.g. the vertex list's subset of the cloth vertices
// of covered triangles, kernels::raster::vertices): head (ceil(count / 64), 1, 1, count),
// then the ids; dispatched indirectly over it.
layout(std430, set = 0, binding = 6) readonly buffer Vertices { uint head[4]; uint v[]; } list;
#else
layout(std430, set = 0, binding = 6) readonly buffer Vertices { uint v[]; } list;
#endif
layout(set = 0, binding = 7, rgba32f) writeonly uniform image2D light;
// The lobes summed here: those not in kernels::btf::basis::BasisData::pixel_lobes (which
// `btf env basis` looks up at each pixel).
layout(std430, set = 0, binding = 8) readonly buffer VertexLobes { uint j[]; } vlobes;

#include "basis_light.glsl"

void store_light(uint v, uint first, vec3 l[RANK]) {
    float f[RANK * 3u];
    for (uint q = 0u; q < RANK; q++) {
        f[3u * q] = l[q].x;
        f[3u * q + 1u] = l[q].y;
        f[3u * q + 2u] = l[q].z;
    }
    for (uint i = 0u; i < RANK * 3u / 4u; i++) {
        imageStore(light, light_texel(v, first + i),
                   vec4(f[4u * i], f[4u * i + 1u], f[4u * i + 2u], f[4u * i + 3u]));
    }
}

void main() {
    uint i = gl_GlobalInvocationID.x;
#ifdef ENV_VERTICES_LISTED
    if (i >= list.head[3]) return;
#else
    if (i >= pc.count) return;
#endif
    uint v = list.v[i];
    if (v >= pc.vertex_count) return;
    vec3 n = nrm.n[v].xyz;
    float len = length(n);
    n = len > 0.0 ? n / len : vec3(0.0, 0.0, 1.0);
    vec4 tg = tan.t[v];
    float hand = tg.w >= 0.0 ? 1.0 : -1.0;
    vec3 tt = tg.xyz - n * dot(n, tg.xyz);
    if (dot(tt, tt) < 1e-12) tt = abs(n.x) < 0.9 ? cross(n, vec3(1.0, 0.0, 0.0)) : cross(n, vec3(0.0, 1.0, 0.0));
    vec3 t = normalize(tt);
    vec3 bt = hand * cross(n, t);
    vec3 front[RANK];
    vec3 back[RANK];
    for (uint q = 0u; q < RANK; q++) {
        front[q] = vec3(0.0);
        back[q] = vec3(0.0);
    }
    uint J = pc.lobes;
    for (uint m = 0u; m < pc.lobe_count; m++) {
        uint j = vlobes.j[m];
        vec4 p = lobes.v[2u * j];
        vec3 s = lobes.v[2u * j + 1u].rgb * (vertex_vis.v[v * J + j] * (1.0 / PI));
        vec3 local = vec3(dot(p.xyz, t), dot(p.xyz, bt), dot(p.xyz, n));
        add_lobe(front, s, local, j);
        add_lobe(back, s, vec3(local.xy, -local.z), j);
    }
    store_light(v, 0u, front);
    store_light(v, LIGHT_BACK, back);
    imageStore(light, light_texel(v, LIGHT_NORMAL), vec4(n, 0.0));
}
