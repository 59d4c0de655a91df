#version 450
// Texture-space irradiance: E per texel from directional and point lights, each shadowed by
// a ray through the mesh's BVH (the CPU BVH flattened; the same traversal and two-sided
// Moller-Trumbore test as src/geom/bvh.rs). White lights: E is written to rgb alike.
layout(local_size_x = 8, local_size_y = 8) in;

layout(push_constant) uniform Push {
    uint size;     // texture is size x size
    uint lights;
    float bias;    // shadow-ray origin offset along the normal (mm)
} pc;

layout(std430, set = 0, binding = 0) readonly buffer Pos { vec4 v[]; } pos;       // xyz, flag
layout(std430, set = 0, binding = 1) readonly buffer Nrm { vec4 v[]; } nrm;       // xyz, area
layout(std430, set = 0, binding = 2) readonly buffer Nodes { vec4 v[]; } nodes;   // 2 per node
layout(std430, set = 0, binding = 3) readonly buffer Tris { vec4 v[]; } tris;     // 3 per tri
layout(std430, set = 0, binding = 4) readonly buffer Lights { vec4 v[]; } lights; // 2 per light
layout(std430, set = 0, binding = 5) writeonly buffer Irr { vec4 v[]; } irr;

bool hit_tri(vec3 o, vec3 d, uint t, float tmax) {
    vec3 a = tris.v[3u * t].xyz;
    vec3 e1 = tris.v[3u * t + 1u].xyz;
    vec3 e2 = tris.v[3u * t + 2u].xyz;
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

bool any_hit(vec3 o, vec3 d, float tmax) {
    vec3 inv = 1.0 / d;
    uint stack[64];
    uint sp = 1u;
    stack[0] = 0u;
    while (sp > 0u) {
        sp--;
        uint ni = stack[sp];
        vec4 lo = nodes.v[2u * ni];
        vec4 hi = nodes.v[2u * ni + 1u];
        vec3 t0 = (lo.xyz - o) * inv;
        vec3 t1 = (hi.xyz - o) * inv;
        vec3 tmin = min(t0, t1);
        vec3 tmx = max(t0, t1);
        float tnear = max(max(max(tmin.x, tmin.y), tmin.z), 0.0);
        float tfar = min(min(min(tmx.x, tmx.y), tmx.z), tmax);
        if (tnear > tfar) continue;
        uint first = floatBitsToUint(lo.w);
        uint count = floatBitsToUint(hi.w);
        if (count > 0u) {
            for (uint t = first; t < first + count; t++) {
                if (hit_tri(o, d, t, tmax)) return true;
            }
        } else if (sp + 2u <= 64u) {
            stack[sp] = first;
            stack[sp + 1u] = first + 1u;
            sp += 2u;
        }
    }
    return false;
}

void main() {
    uvec2 xy = gl_GlobalInvocationID.xy;
    if (xy.x >= pc.size || xy.y >= pc.size) return;
    uint i = xy.y * pc.size + xy.x;
    vec4 p4 = pos.v[i];
    if (p4.w == 0.0) {
        irr.v[i] = vec4(0.0);
        return;
    }
    vec3 p = p4.xyz;
    vec3 n = nrm.v[i].xyz;
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
    irr.v[i] = vec4(e, e, e, 1.0);
}
