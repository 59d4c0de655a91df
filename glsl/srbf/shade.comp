#version 450
// Per-vertex shading with precomputed transfer: L_o,v = albedo * sum_k t_vk c_k, where t_v
// projects V(w) max(0, n.w) / pi onto the basis and c_k are the lighting's coefficients.
// The transfer is stored in groups of four basis functions, group-major:
// t4[g * vertices + v] = (t_v,4g .. t_v,4g+3), zero-padded; neighbouring invocations read
// neighbouring vec4s (coalesced on GPUs, wide loads on lavapipe). The coefficients are the
// same for every invocation and stay in cache. No shared memory: barriers are expensive on
// CPU implementations and buy nothing here.
layout(local_size_x = 64) in;

layout(push_constant) uniform Push {
    vec4 albedo;   // rgb
    uint vertices;
    uint groups;   // ceil(basis / 4)
} pc;

layout(std430, set = 0, binding = 0) readonly buffer Transfer { vec4 t[]; } transfer;
// The lighting's coefficients as a uniform buffer: every invocation reads the same ones, and
// uniform-buffer loads with a dynamically uniform index are scalar (on lavapipe a storage
// buffer load here is a per-lane gather: it cost three quarters of the pass).
const uint MAX_BASIS = 1024u;
layout(std140, set = 0, binding = 1) uniform Coeffs { vec4 v[MAX_BASIS]; } coeffs; // zero-padded
layout(std430, set = 0, binding = 2) writeonly buffer Radiance { vec4 v[]; } radiance;

void main() {
    uint v = gl_GlobalInvocationID.x;
    if (v >= pc.vertices) return;
    vec3 sum = vec3(0.0);
    uint index = v;
    for (uint g = 0u; g < pc.groups; g++) {
        vec4 t = transfer.t[index];
        uint k = 4u * g;
        sum += t.x * coeffs.v[k].rgb + t.y * coeffs.v[k + 1u].rgb + t.z * coeffs.v[k + 2u].rgb
            + t.w * coeffs.v[k + 3u].rgb;
        index += pc.vertices;
    }
    radiance.v[v] = vec4(pc.albedo.rgb * sum, 1.0);
}
