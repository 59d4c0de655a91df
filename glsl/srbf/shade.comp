#version 450
// Per-vertex shading with precomputed transfer: L_o,v = albedo * sum_k t_vk c_k, where t_v
// projects V(w) max(0, n.w) / pi onto the basis and c_k are the lighting's coefficients.
layout(local_size_x = 64) in;

layout(push_constant) uniform Push {
    vec4 albedo;   // rgb
    uint vertices;
    uint basis;
} pc;

layout(std430, set = 0, binding = 0) readonly buffer Transfer { float t[]; } transfer; // vertex-major
layout(std430, set = 0, binding = 1) readonly buffer Coeffs { vec4 v[]; } coeffs;
layout(std430, set = 0, binding = 2) writeonly buffer Radiance { vec4 v[]; } radiance;

// The lighting coefficients, shared by the workgroup (read once per group, not per vertex).
const uint CHUNK = 256u;
shared vec3 c_shared[CHUNK];

void main() {
    uint v = gl_GlobalInvocationID.x;
    uint local = gl_LocalInvocationID.x;
    vec3 sum = vec3(0.0);
    uint base = v * pc.basis;
    for (uint start = 0u; start < pc.basis; start += CHUNK) {
        uint n = min(CHUNK, pc.basis - start);
        for (uint i = local; i < n; i += gl_WorkGroupSize.x) {
            c_shared[i] = coeffs.v[start + i].rgb;
        }
        barrier();
        if (v < pc.vertices) {
            for (uint i = 0u; i < n; i++) {
                sum += transfer.t[base + start + i] * c_shared[i];
            }
        }
        barrier();
    }
    if (v < pc.vertices) {
        radiance.v[v] = vec4(pc.albedo.rgb * sum, 1.0);
    }
}
