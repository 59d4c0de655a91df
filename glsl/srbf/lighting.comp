#version 450
// SRBF lighting in the transfer basis: for each basis lobe k (axis eta_k, sharpness mu),
// c_k = sum_j amp_j <G(R xi_j, lambda_j), G(eta_k, mu)>, with the closed-form inner product of
// two spherical Gaussians. Rotating the environment by R only rotates the lobe axes.
layout(local_size_x = 64) in;

layout(push_constant) uniform Push {
    vec4 rot[3];   // columns of R (xyz)
    uint lobes;
    uint basis;
    float mu;      // sharpness of every basis lobe
} pc;

layout(std430, set = 0, binding = 0) readonly buffer LobeAxes { vec4 v[]; } lobe_axes;   // xyz, sharpness
layout(std430, set = 0, binding = 1) readonly buffer LobeAmps { vec4 v[]; } lobe_amps;   // rgb
layout(std430, set = 0, binding = 2) readonly buffer BasisAxes { vec4 v[]; } basis_axes; // xyz
layout(std430, set = 0, binding = 3) writeonly buffer Coeffs { vec4 v[]; } coeffs;       // rgb

const float TWO_PI = 6.28318530718;

// Integral of the product of two unit-amplitude SGs, without the cancellation of
// |r| - l1 - l2 (it equals -2 l1 l2 (1 - a1.a2) / (|r| + l1 + l2)).
float sg_inner(vec3 a1, float l1, vec3 a2, float l2) {
    float r = length(l1 * a1 + l2 * a2);
    float e = -2.0 * l1 * l2 * max(1.0 - dot(a1, a2), 0.0) / (r + l1 + l2);
    float tail = r > 1e-3 ? (1.0 - exp(-2.0 * r)) / r : 2.0 - 2.0 * r;
    return TWO_PI * exp(e) * tail;
}

void main() {
    uint k = gl_GlobalInvocationID.x;
    if (k >= pc.basis) return;
    mat3 R = mat3(pc.rot[0].xyz, pc.rot[1].xyz, pc.rot[2].xyz);
    vec3 eta = basis_axes.v[k].xyz;
    vec3 sum = vec3(0.0);
    for (uint j = 0u; j < pc.lobes; j++) {
        vec4 a = lobe_axes.v[j];
        vec3 axis = normalize(R * a.xyz);
        sum += lobe_amps.v[j].rgb * sg_inner(axis, a.w, eta, pc.mu);
    }
    coeffs.v[k] = vec4(sum, 0.0);
}
