#version 450
// CTA shading per vertex (glsl/srbf/glossy.comp's view lookup): the view toward the camera in
// the vertex's tangent frame, its four bilinear taps in the N x N parabolic grid, the
// interpolated view-factor row u_w = sum_t w_t W_c[j_t] (r_w), and the radiance
// B = albedo * sum_a u_v[a] sum_b M_c[a, b] u_w[b], M_c from pass `srbf cta project`.
layout(local_size_x = 64) in;

layout(push_constant) uniform Push {
    vec4 camera;   // xyz, model units
    vec4 albedo;   // rgb
    uint vertices;
    uint grid;     // N
    uint rv;
    uint rw;
} pc;

layout(std430, set = 0, binding = 0) readonly buffer Coeffs { float u[]; } vcoeffs;   // n x r_v
layout(std430, set = 0, binding = 1) readonly buffer Cluster { uint c[]; } cluster;   // n
layout(std430, set = 0, binding = 2) readonly buffer View { float w[]; } view;         // C x V x r_w
layout(std430, set = 0, binding = 3) readonly buffer M { vec4 v[]; } m;               // C x r_v x r_w
layout(std430, set = 0, binding = 4) readonly buffer Points { vec4 v[]; } points;
layout(std430, set = 0, binding = 5) readonly buffer Normals { vec4 v[]; } normals;
layout(std430, set = 0, binding = 6) writeonly buffer Radiance { vec4 v[]; } radiance;

const uint MAX_RW = 32u;

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
    uvec2 cell = min(uvec2(floor(u)), uvec2(pc.grid - 2u));
    vec2 f = u - vec2(cell);
    uint views = pc.grid * pc.grid;
    uint j00 = cell.y * pc.grid + cell.x;
    uint idx[4] = uint[4](j00, j00 + 1u, j00 + pc.grid, j00 + pc.grid + 1u);
    float wt[4] = float[4]((1.0 - f.x) * (1.0 - f.y), f.x * (1.0 - f.y), (1.0 - f.x) * f.y, f.x * f.y);
    uint c = cluster.c[v];
    float uw[MAX_RW];
    for (uint k = 0u; k < pc.rw; k++) {
        float sum = 0.0;
        for (uint tap = 0u; tap < 4u; tap++) {
            sum += wt[tap] * view.w[(c * views + idx[tap]) * pc.rw + k];
        }
        uw[k] = sum;
    }
    vec3 sum = vec3(0.0);
    uint mbase = c * pc.rv * pc.rw;
    for (uint i = 0u; i < pc.rv; i++) {
        vec3 row = vec3(0.0);
        for (uint k = 0u; k < pc.rw; k++) {
            row += m.v[mbase + i * pc.rw + k].rgb * uw[k];
        }
        sum += vcoeffs.u[v * pc.rv + i] * row;
    }
    radiance.v[v] = vec4(pc.albedo.rgb * sum, 1.0);
}
