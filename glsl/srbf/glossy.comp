#version 450
// Glossy shading (src/kernels/srbf/glossy.rs; `GlossyTransfer::shade` is the CPU twin): per
// vertex, the view direction toward the camera in the vertex's tangent frame (Duff et al.
// 2017, built from the normal alone), clamped onto the horizon below it, mapped to the
// parabolic disk p = (x, y) / (1 + z) and looked up bilinearly in the N x N view grid; the
// radiance is B = albedo * sum_taps w_t (T_v[j_t] . c), T_v[j] the vertex's transfer row
// toward node j (K floats, rows vertex-major) and c the lighting coefficients of pass
// `srbf lighting` (a uniform buffer read at uniform indices).
layout(local_size_x = 64) in;

layout(push_constant) uniform Push {
    vec4 camera;   // xyz, model units
    vec4 albedo;   // rgb
    uint vertices;
    uint grid;     // N
    uint basis;    // K
} pc;

layout(std430, set = 0, binding = 0) readonly buffer Rows { float t[]; } rows;
layout(std430, set = 0, binding = 1) readonly buffer Points { vec4 v[]; } points;
layout(std430, set = 0, binding = 2) readonly buffer Normals { vec4 v[]; } normals;
const uint MAX_BASIS = 1024u;
layout(std140, set = 0, binding = 3) uniform Coeffs { vec4 v[MAX_BASIS]; } coeffs;
layout(std430, set = 0, binding = 4) writeonly buffer Radiance { vec4 v[]; } radiance;

void main() {
    uint v = gl_GlobalInvocationID.x;
    if (v >= pc.vertices) return;
    vec3 x = points.v[v].xyz;
    vec3 n = normals.v[v].xyz;
    float sgn = n.z >= 0.0 ? 1.0 : -1.0;
    float a = -1.0 / (sgn + n.z);
    float b = n.x * n.y * a;
    vec3 t = vec3(1.0 + sgn * n.x * n.x * a, sgn * b, -sgn * n.x);
    vec3 bt = vec3(b, sgn + n.y * n.y * a, -n.y);
    vec3 o = pc.camera.xyz - x;
    if (dot(o, o) == 0.0) o = n;
    vec3 l = vec3(dot(t, o), dot(bt, o), max(dot(n, o), 0.0));
    if (l.x == 0.0 && l.y == 0.0 && l.z == 0.0) l = vec3(1.0, 0.0, 0.0);
    l = normalize(l);
    float s = float(pc.grid - 1u);
    vec2 p = l.xy / (1.0 + l.z);
    vec2 u = clamp((p + 1.0) * 0.5 * s, vec2(0.0), vec2(s));
    uvec2 c = min(uvec2(floor(u)), uvec2(pc.grid - 2u));
    vec2 f = u - vec2(c);
    uint views = pc.grid * pc.grid;
    uint j00 = c.y * pc.grid + c.x;
    uint idx[4] = uint[4](j00, j00 + 1u, j00 + pc.grid, j00 + pc.grid + 1u);
    float w[4] = float[4]((1.0 - f.x) * (1.0 - f.y), f.x * (1.0 - f.y), (1.0 - f.x) * f.y, f.x * f.y);
    vec3 sum = vec3(0.0);
    for (uint tap = 0u; tap < 4u; tap++) {
        uint base = (v * views + idx[tap]) * pc.basis;
        vec3 r = vec3(0.0);
        for (uint k = 0u; k < pc.basis; k++) {
            r += rows.t[base + k] * coeffs.v[k].rgb;
        }
        sum += w[tap] * r;
    }
    radiance.v[v] = vec4(pc.albedo.rgb * sum, 1.0);
}
