// Pass `srbf glossy sharp`: the compact lobes of a glossy run (src/kernels/srbf/glossy_sharp.rs;
// `GlossyCompact::add` is the CPU twin), added per vertex onto the radiance the glossy or CTA
// shade pass wrote:
//   B_v += albedo * sum_j E_j V_v(w_j) rho(w_j, o_v) max(0, n_v . w_j),
// over taps j, E_j the tap's share of its lobe's integral (amplitude x 2 pi (1 - e^(-2
// lambda)) / lambda), o_v the view direction toward the camera clamped onto the horizon
// (src/geom/brdf.rs view_direction) and rho the modified Phong BRDF. The includer defines tap
// j at vertex v,
//   float seen_at(uint j, vec3 x, vec3 n, out vec3 w, out vec3 e)
// (the tap's direction w, its E_j per channel, and 1.0 where it is seen, else 0.0): a grid
// texel centre and its visibility bit (glossy_sharp.comp, from the taps pass `srbf sharp`
// wrote: one a point source, four a resolved lobe), or a lobe's exact rotated axis and a
// shadow ray (glossy_sharp_rays.comp).
// One invocation per vertex, in the vertices' own order.

layout(push_constant) uniform Push {
    vec4 rot[3];   // columns of R (xyz)
    vec4 camera;   // xyz, model units
    vec4 albedo;   // rgb
    vec4 brdf;     // Phong exponent, kd, ks
    uint lobes;    // taps: grid, sharp::tap_count; rays, one a lobe
    uint vertices;
    uint words;    // visibility words per vertex (grid taps)
    float offset;  // shadow ray origin offset along the normal (ray taps)
} pc;

layout(std430, set = 0, binding = 0) readonly buffer Points { vec4 v[]; } points;
layout(std430, set = 0, binding = 1) readonly buffer Normals { vec4 v[]; } normals;
layout(std430, set = 0, binding = 2) buffer Radiance { vec4 v[]; } radiance;

float seen_at(uint j, vec3 x, vec3 n, out vec3 w, out vec3 e);

// Brdf::view_direction.
vec3 view_direction(vec3 n, vec3 x) {
    vec3 o = pc.camera.xyz - x;
    o -= min(dot(o, n), 0.0) * n;
    return dot(o, o) > 0.0 ? normalize(o) : n;
}

// Brdf::rho for the modified Phong model (kd / pi + ks (e + 2) / (2 pi) max(0, w . r)^e).
float rho(vec3 n, vec3 w, vec3 o) {
    vec3 r = 2.0 * dot(n, o) * n - o;
    float c = max(dot(w, r), 0.0);
    float e = pc.brdf.x;
    float lobe = c > 0.0 ? pow(c, e) : (e == 0.0 ? 1.0 : 0.0);
    return pc.brdf.y / PI + pc.brdf.z * (e + 2.0) / TAU * lobe;
}

void main() {
    uint v = gl_GlobalInvocationID.x;
    if (v >= pc.vertices) return;
    vec3 x = points.v[v].xyz;
    vec3 n = normals.v[v].xyz;
    vec3 o = view_direction(n, x);
    vec3 sum = vec3(0.0);
    for (uint j = 0u; j < pc.lobes; j++) {
        vec3 w, e;
        float seen = seen_at(j, x, n, w, e);
        sum += e * (seen * max(dot(n, w), 0.0) * rho(n, w, o));
    }
    radiance.v[v] += vec4(pc.albedo.rgb * sum, 0.0);
}
