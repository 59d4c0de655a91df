#version 450
// The character's one skinning pass: linear blend skinning of every vertex's position, normal
// and tangent (the tangent frame follows the UVs: +u, with the handedness in w). The normal
// is renormalised (LBS shrinks it); the tangent is skinned, then made orthogonal to the posed
// normal (Gram-Schmidt), so the frame stays orthonormal in every pose. A vertex whose blended
// direction vanishes keeps its rest direction (normal) or a perpendicular (tangent), as the
// CPU twin (kernels::pose::cpu) does.
layout(local_size_x = 64) in;

layout(push_constant) uniform Push {
    uint vertex_count;
} pc;

layout(std430, set = 0, binding = 0) readonly buffer Joints { mat4 m[]; } joints;
layout(std430, set = 0, binding = 1) readonly buffer RestPositions { vec4 p[]; } rest_pos;
layout(std430, set = 0, binding = 2) readonly buffer RestNormals { vec4 n[]; } rest_nrm;
layout(std430, set = 0, binding = 3) readonly buffer RestTangents { vec4 t[]; } rest_tan;
layout(std430, set = 0, binding = 4) readonly buffer VertexJoints { uvec2 j[]; } vjoints;
layout(std430, set = 0, binding = 5) readonly buffer VertexWeights { vec4 w[]; } vweights;
layout(std430, set = 0, binding = 6) writeonly buffer Positions { vec4 p[]; } pos;
layout(std430, set = 0, binding = 7) writeonly buffer Normals { vec4 n[]; } nrm;
layout(std430, set = 0, binding = 8) writeonly buffer Tangents { vec4 t[]; } tan;

mat4 blend(uvec2 packed, vec4 w) {
    uvec4 j = uvec4(packed.x & 0xffffu, packed.x >> 16, packed.y & 0xffffu, packed.y >> 16);
    mat4 m = mat4(0.0);
    if (w.x != 0.0) m += joints.m[j.x] * w.x;
    if (w.y != 0.0) m += joints.m[j.y] * w.y;
    if (w.z != 0.0) m += joints.m[j.z] * w.z;
    if (w.w != 0.0) m += joints.m[j.w] * w.w;
    return m;
}

// A unit vector perpendicular to the unit vector n.
// +x for a zero n (a degenerate vertex), as the CPU twin.
vec3 perpendicular(vec3 n) {
    vec3 a = abs(n.x) < 0.9 ? vec3(1.0, 0.0, 0.0) : vec3(0.0, 1.0, 0.0);
    vec3 p = cross(n, a);
    return dot(p, p) > 0.0 ? normalize(p) : vec3(1.0, 0.0, 0.0);
}

void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i >= pc.vertex_count) return;
    mat4 m = blend(vjoints.j[i], vweights.w[i]);
    pos.p[i] = vec4((m * vec4(rest_pos.p[i].xyz, 1.0)).xyz, 1.0);
    vec3 n = (m * vec4(rest_nrm.n[i].xyz, 0.0)).xyz;
    float len = length(n);
    n = len > 0.0 ? n / len : rest_nrm.n[i].xyz;
    nrm.n[i] = vec4(n, 0.0);
    vec4 rest_t = rest_tan.t[i];
    vec3 t = (m * vec4(rest_t.xyz, 0.0)).xyz;
    t -= n * dot(n, t);
    float tl = length(t);
    tan.t[i] = vec4(tl > 1e-20 ? t / tl : perpendicular(n), rest_t.w);
}
