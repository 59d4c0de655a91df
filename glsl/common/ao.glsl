// Per-sphere ambient occlusion, shared by the AO kernels. Mirrors src/kernels/ao/formula.rs
// operation for operation, so the CPU implementation reproduces the GPU to rounding.
#ifndef VKSHADE_AO_GLSL
#define VKSHADE_AO_GLSL

const float AO_PI = 3.14159265358979;

// Cosine-weighted occluded fraction of the hemisphere above the normal, for a sphere at angle
// theta (cos_t) from the normal and h = distance / radius (> 1). Exact for spheres above,
// straddling and below the horizon (Lagarde & de Rousiers 2014, sec. 3.2).
float sphere_occlusion(float cos_t, float h) {
    h = max(h, 1.0 + 1e-6);
    cos_t = clamp(cos_t, -1.0, 1.0);
    float h2 = h * h;
    float hc = h * cos_t;
    if (hc >= 1.0) return cos_t / h2;
    if (hc <= -1.0) return 0.0;
    float k2 = 1.0 - hc * hc;
    float sin2 = max(1.0 - cos_t * cos_t, 1e-12);
    float a = clamp(-cos_t * sqrt((h2 - 1.0) / sin2), -1.0, 1.0);
    float term = (cos_t * acos(a) - sqrt(k2 * (h2 - 1.0))) / h2;
    return clamp((term + atan(sqrt(k2 / (h2 - 1.0)))) / AO_PI, 0.0, 1.0);
}

// Whether any of the sphere (distance / radius h, cosine cos_t of its centre to the normal)
// lies above the horizon: the exact sphere_occlusion is positive exactly when h cos_t > -1.
// For a caller that needs only whether the sphere counts (a branch of acos, atan and three
// square roots less). kernels::ao::formula::sphere_above_horizon.
bool sphere_above_horizon(float cos_t, float h) {
    return max(h, 1.0 + 1e-6) * clamp(cos_t, -1.0, 1.0) > -1.0;
}

// Table coordinates: u = psi / 2pi = 1 - sqrt(1 - 1/h^2), v = theta / pi.
vec2 ao_table_coords(float cos_t, float h) {
    float inv_h2 = 1.0 / max(h * h, 1.0);
    float u = 1.0 - sqrt(max(1.0 - inv_h2, 0.0));
    float v = acos(clamp(cos_t, -1.0, 1.0)) * (1.0 / AO_PI);
    return clamp(vec2(u, v), 0.0, 1.0);
}

// Right-handed orthonormal basis completing unit n (Duff et al. 2017).
void ao_basis(vec3 n, out vec3 t, out vec3 b) {
    float s = n.z >= 0.0 ? 1.0 : -1.0;
    float a = -1.0 / (s + n.z);
    float c = n.x * n.y * a;
    t = vec3(1.0 + s * n.x * n.x * a, s * c, -s * n.x);
    b = vec3(c, s + n.y * n.y * a, -n.y);
}

#endif
