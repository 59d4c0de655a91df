#version 450
// Shadowing and transmission per mesh vertex (pass `sss vertex light`), for the irradiance
// pass to interpolate over each triangle (glsl/sss/irradiance.comp): the head has far fewer
// vertices than a 512^2 texture has texels, and a BVH ray is the costly part.
// Per vertex (position, unit normal; src/kernels/sss/cpu.rs vertex_frames):
// - visibility: bit l set when light l is not blocked by the mesh along a ray from
//   p + n * bias toward it (cast whatever the sign of n.l: the texel's own cosine decides
//   the terminator). The same traversal and two-sided Moller-Trumbore test as
//   src/geom/bvh.rs.
// - transmission through thin parts (mode != 0): a ray from just inside along -n finds the
//   back surface at thickness t; its irradiance E_b (its own rays) times R_tot - F(t) per
//   channel (the profile beyond t: a locally flat slab lit from behind): (rgb, t).
// The CPU twin is src/kernels/sss/cpu.rs.
layout(local_size_x = 64) in;

layout(push_constant) uniform Push {
    vec4 tail[3];  // per channel: dipole (alpha'/2, sigma_tr, z_r, z_v), Burley (A, d, 0, 0)
    uint vertices;
    uint lights;
    float bias;    // shadow-ray origin offset along the normal (mm)
    uint mode;     // transmission: 0 off, 1 dipole, 2 Burley
    float max_t;   // thickest part that transmits (mm)
} pc;

layout(std430, set = 0, binding = 0) readonly buffer Verts { vec4 v[]; } verts;   // pos, normal
// The BVH as images (row BVH_ROW; lavapipe fetches a texel's four channels at once): nodes
// 2 texels each (lo xyz, first; hi xyz, link word), triangles 3 (a, e1, e2), float bits.
const uint BVH_ROW = 1024u;
layout(set = 0, binding = 1, rgba32ui) readonly uniform uimage2D nodes;
layout(set = 0, binding = 2, rgba32ui) readonly uniform uimage2D tris;

uvec4 bvh_node(uint k) {
    return imageLoad(nodes, ivec2(k % BVH_ROW, k / BVH_ROW));
}

vec3 tri_row(uint k) {
    return uintBitsToFloat(imageLoad(tris, ivec2(k % BVH_ROW, k / BVH_ROW)).xyz);
}
const uint MAX_LIGHTS = 16u; // cpu::MAX_LIGHTS
// A uniform buffer: lavapipe reads it at the loop's uniform index as a scalar (a storage
// buffer would be loaded lane by lane, component by component).
layout(std140, set = 0, binding = 3) uniform Lights { vec4 v[2 * MAX_LIGHTS]; } lights; // 2 per light
// Outputs as images (vertex v at (v % VERTEX_ROW, v / VERTEX_ROW)): the irradiance pass
// gathers them with one texel fetch each.
const uint VERTEX_ROW = 1024u;
layout(set = 0, binding = 4, r32ui) writeonly uniform uimage2D vis;
layout(set = 0, binding = 5, rgba32f) writeonly uniform image2D vtrans; // rgb, t

// Parameter of the hit of triangle t in (0, tmax], or -1.
float hit_t(vec3 o, vec3 d, uint t, float tmax) {
    vec3 a = tri_row(3u * t);
    vec3 e1 = tri_row(3u * t + 1u);
    vec3 e2 = tri_row(3u * t + 2u);
    vec3 p = cross(d, e2);
    float det = dot(e1, p);
    if (abs(det) < 1e-12) return -1.0;
    float inv = 1.0 / det;
    vec3 s = o - a;
    float u = dot(s, p) * inv;
    if (u < 0.0 || u > 1.0) return -1.0;
    vec3 q = cross(s, e1);
    float v = dot(d, q) * inv;
    if (v < 0.0 || u + v > 1.0) return -1.0;
    float t_hit = dot(e2, q) * inv;
    return (t_hit > 0.0 && t_hit <= tmax) ? t_hit : -1.0;
}

bool hit_tri(vec3 o, vec3 d, uint t, float tmax) {
    vec3 a = tri_row(3u * t);
    vec3 e1 = tri_row(3u * t + 1u);
    vec3 e2 = tri_row(3u * t + 2u);
    vec3 p = cross(d, e2);
    float det = dot(e1, p);
    if (abs(det) < 1e-12) return false;
    float inv = 1.0 / det;
    vec3 s = o - a;
    float u = dot(s, p) * inv;
    if (u < 0.0 || u > 1.0) return false;
    vec3 q = cross(s, e1);
    float v = dot(d, q) * inv;
    if (v < 0.0 || u + v > 1.0) return false;
    float t_hit = dot(e2, q) * inv;
    return t_hit > 0.0 && t_hit <= tmax;
}

// Stackless traversal (src/kernels/sss/posed.rs link_words): a node's hi.w is its
// triangle count | its skip << 8, the node visited next when the ray does not enter it;
// entering an inner node goes to its left child, a leaf's triangles are tested and then its
// skip is taken. The root's skip (0xffffff) ends it; every step moves forward in the
// depth-first order (MAX_STEPS only guards a malformed table).
const uint LINK_END = 0xffffffu;
const uint MAX_STEPS = 1u << 22u;

bool any_hit(vec3 o, vec3 d, float tmax) {
    vec3 inv = 1.0 / d;
    uint ni = 0u;
    for (uint step = 0u; ni != LINK_END && step < MAX_STEPS; step++) {
        uvec4 lo_u = bvh_node(2u * ni);
        uvec4 hi_u = bvh_node(2u * ni + 1u);
        vec3 lo = uintBitsToFloat(lo_u.xyz);
        vec3 hi = uintBitsToFloat(hi_u.xyz);
        vec3 t0 = (lo - o) * inv;
        vec3 t1 = (hi - o) * inv;
        vec3 tmin = min(t0, t1);
        vec3 tmx = max(t0, t1);
        float tnear = max(max(max(tmin.x, tmin.y), tmin.z), 0.0);
        float tfar = min(min(min(tmx.x, tmx.y), tmx.z), tmax);
        bool meets = !(tnear > tfar);
        uint first = lo_u.w;
        uint count = hi_u.w & 0xffu;
        uint n = meets ? count : 0u;
        for (uint t = first; t < first + n; t++) {
            if (hit_tri(o, d, t, tmax)) return true;
        }
        ni = (meets && count == 0u) ? first : hi_u.w >> 8u;
    }
    return false;
}

// Nearest hit in (0, tmax]: (t, triangle), or t < 0. The stackless traversal of any_hit,
// the far bound shrinking to the best hit so far.
vec2 closest_hit(vec3 o, vec3 d, float tmax) {
    vec3 inv = 1.0 / d;
    float best = -1.0;
    uint best_tri = 0u;
    uint ni = 0u;
    for (uint step = 0u; ni != LINK_END && step < MAX_STEPS; step++) {
        uvec4 lo_u = bvh_node(2u * ni);
        uvec4 hi_u = bvh_node(2u * ni + 1u);
        vec3 lo = uintBitsToFloat(lo_u.xyz);
        vec3 hi = uintBitsToFloat(hi_u.xyz);
        vec3 t0 = (lo - o) * inv;
        vec3 t1 = (hi - o) * inv;
        vec3 tmin = min(t0, t1);
        vec3 tmx = max(t0, t1);
        float tnear = max(max(max(tmin.x, tmin.y), tmin.z), 0.0);
        float tfar = min(min(min(tmx.x, tmx.y), tmx.z), best >= 0.0 ? best : tmax);
        bool meets = !(tnear > tfar);
        uint first = lo_u.w;
        uint count = hi_u.w & 0xffu;
        uint n = meets ? count : 0u;
        for (uint t = first; t < first + n; t++) {
            float th = hit_t(o, d, t, tmax);
            if (th >= 0.0 && (best < 0.0 || th < best)) {
                best = th;
                best_tri = t;
            }
        }
        ni = (meets && count == 0u) ? first : hi_u.w >> 8u;
    }
    return vec2(best, uintBitsToFloat(best_tri));
}

// Visibility bits of the lights from p (normal n), rays from p + n * bias.
uint visibility(vec3 p, vec3 n) {
    vec3 o = p + n * pc.bias;
    uint bits = 0u;
    for (uint l = 0u; l < pc.lights; l++) {
        vec4 a = lights.v[2u * l];
        vec3 dir;
        float tmax;
        if (a.w == 0.0) {
            dir = a.xyz;
            tmax = uintBitsToFloat(0x7f800000u);
        } else {
            vec3 dd = a.xyz - p;
            float dist = length(dd);
            dir = dd / dist;
            tmax = dist - pc.bias;
        }
        if (!any_hit(o, dir, tmax)) bits |= 1u << l;
    }
    return bits;
}

// Irradiance at p (normal n) from every light, shadow rays from p + n * bias.
float irradiance_at(vec3 p, vec3 n) {
    vec3 o = p + n * pc.bias;
    float e = 0.0;
    for (uint l = 0u; l < pc.lights; l++) {
        vec4 a = lights.v[2u * l];
        float strength = lights.v[2u * l + 1u].x;
        vec3 dir;
        float tmax;
        if (a.w == 0.0) {
            dir = a.xyz;
            tmax = uintBitsToFloat(0x7f800000u);
        } else {
            vec3 dd = a.xyz - p;
            float dist = length(dd);
            dir = dd / dist;
            tmax = dist - pc.bias;
            strength = strength / (dist * dist);
        }
        float c = dot(n, dir);
        if (c <= 0.0 || strength == 0.0) continue;
        if (any_hit(o, dir, tmax)) continue;
        e += strength * c;
    }
    return e;
}

float tail(uint c, float t) {
    vec4 p = pc.tail[c];
    if (pc.mode == 1u) {
        float dr = sqrt(t * t + p.z * p.z);
        float dv = sqrt(t * t + p.w * p.w);
        return p.x * (p.z * exp(-p.y * dr) / dr + p.w * exp(-p.y * dv) / dv);
    }
    return p.x * (0.25 * exp(-t / p.y) + 0.75 * exp(-t / (3.0 * p.y)));
}

void main() {
    uint v = gl_GlobalInvocationID.x;
    if (v >= pc.vertices) return;
    vec3 p = verts.v[2u * v].xyz;
    vec3 n = verts.v[2u * v + 1u].xyz;
    ivec2 at = ivec2(v % VERTEX_ROW, v / VERTEX_ROW);
    imageStore(vis, at, uvec4(visibility(p, n)));
    vec4 tr = vec4(0.0);
    if (pc.mode != 0u) {
        vec3 o = p - n * pc.bias;
        vec2 h = closest_hit(o, -n, pc.max_t);
        if (h.x >= 0.0) {
            uint k = floatBitsToUint(h.y);
            vec3 nb = normalize(cross(tri_row(3u * k + 1u), tri_row(3u * k + 2u)));
            if (dot(nb, n) > 0.0) nb = -nb;
            vec3 xb = o - n * h.x;
            float eb = irradiance_at(xb, nb);
            float thick = h.x + pc.bias;
            tr = vec4(eb * tail(0u, thick), eb * tail(1u, thick), eb * tail(2u, thick), thick);
        }
    }
    imageStore(vtrans, at, tr);
}
