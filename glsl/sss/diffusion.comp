#version 450
// Texture-space subsurface diffusion, importance sampled (p(r) ~ Rd(r) r per channel):
// B(xo) = K(R) * mean of E over accepted samples. Each sample is a tangent-plane offset of
// radius r (inverse CDF: table for the dipole, closed form for Burley) and angle phi, mapped
// to UV by (J^T J)^-1 J^T (the circle becomes the texel's ellipse; area is accounted for
// because the offsets are drawn in surface area, not in UV). A sample reads E and the 3D
// position of its nearest texel. Seams: a sample whose 3D position is not at distance ~r
// (within the tolerance, which exceeds the half-texel rounding) is rejected; B renormalises
// over the accepted ones. The CPU twin is src/kernels/sss/cpu.rs (same sequence and arithmetic).
layout(local_size_x = 8, local_size_y = 8) in;

layout(push_constant) uniform Push {
    vec4 k;          // K(R) per channel (rgb)
    vec4 burley_d;   // Burley d per channel (rgb)
    vec4 burley_pr;  // Burley P(R) per channel (rgb)
    uint size;
    uint samples;
    uint burley;     // 0: dipole table, 1: Burley analytic
    float seam_rel;
    float seam_texels;
} pc;

layout(std430, set = 0, binding = 0) readonly buffer Pos { vec4 v[]; } pos;
layout(std430, set = 0, binding = 1) readonly buffer Nrm { vec4 v[]; } nrm;
layout(std430, set = 0, binding = 2) readonly buffer Dpdu { vec4 v[]; } dpdu;
layout(std430, set = 0, binding = 3) readonly buffer Dpdv { vec4 v[]; } dpdv;
layout(std430, set = 0, binding = 4) readonly buffer Irr { vec4 v[]; } irr;
layout(std430, set = 0, binding = 5) readonly buffer Table { vec4 v[]; } table;  // rgb radii
layout(std430, set = 0, binding = 6) writeonly buffer Diffuse { vec4 v[]; } diffuse;

const uint TABLE_SIZE = 1024u;
const float TAU = 6.28318530718;

uint pcg(uint v) {
    uint state = v * 747796405u + 2891336453u;
    uint word = ((state >> ((state >> 28u) + 4u)) ^ state) * 277803737u;
    return (word >> 22u) ^ word;
}

float radius(uint c, float u) {
    if (pc.burley == 0u) {
        float t = sqrt(max(u, 0.0)) * float(TABLE_SIZE - 1u);
        uint j = min(uint(t), TABLE_SIZE - 2u);
        float f = t - float(j);
        float a = table.v[j][c];
        float b = table.v[j + 1u][c];
        return a + (b - a) * f;
    }
    float uu = 1.0 - u * pc.burley_pr[c];
    float g = 1.0 + 4.0 * uu * (2.0 * uu + sqrt(1.0 + 4.0 * uu * uu));
    float cb = pow(g, 1.0 / 3.0);
    return max(pc.burley_d[c] * 3.0 * log((1.0 + 1.0 / cb + cb) / (4.0 * uu)), 0.0);
}

// One channel's estimate (called with a constant channel, so component indices are static
// after inlining).
float channel(uint c, uint i, float x, float y, float nf, vec3 po, float eo, float kc,
              float m00, float m01, float m10, float m11, float texel_mm,
              inout uint accepted_all) {
    uint h = pcg(i * 3u + c);
    float off_u = float(h >> 16u) / 65536.0;
    float off_phi = float(h & 0xffffu) / 65536.0;
    float sum = 0.0;
    uint acc = 0u;
    // Angles phi_s = phi_0 + s * golden angle, by rotating (cos, sin) (no sin/cos per sample).
    float phi0 = TAU * off_phi;
    vec2 dir = vec2(cos(phi0), sin(phi0));
    const vec2 STEP = vec2(-0.73736883, -0.67549035); // (cos, sin) of 2 pi 0.618034
    for (uint s = 0u; s < pc.samples; s++) {
        float u = fract((float(s) + 0.5) / float(pc.samples) + off_u);
        float r = radius(c, u);
        float cs = dir.x * r, sn = dir.y * r;
        dir = vec2(dir.x * STEP.x - dir.y * STEP.y, dir.x * STEP.y + dir.y * STEP.x);
        float tx = x + (m00 * cs + m01 * sn) * nf;
        float ty = y + (m10 * cs + m11 * sn) * nf;
        // Nearest texel (E and position at its centre): one gather of each per sample
        // instead of four (lavapipe runs per-lane loads one lane at a time).
        float fx = floor(tx + 0.5), fy = floor(ty + 0.5);
        if (isnan(tx) || isnan(ty) || isinf(tx) || isinf(ty) || fx < 0.0 || fy < 0.0
            || fx >= nf || fy >= nf) continue;
        uint i00 = uint(fy) * pc.size + uint(fx);
        vec4 p00 = pos.v[i00];
        if (p00.w == 0.0) continue;
        float es = irr.v[i00][c];
        vec3 ps = p00.xyz;
        float d = length(ps - po);
        if (abs(d - r) <= pc.seam_rel * r + pc.seam_texels * texel_mm) {
            sum += es;
            acc++;
        }
    }
    accepted_all += acc;
    return acc > 0u ? kc * (sum / float(acc)) : kc * eo;
}

void main() {
    uvec2 xy = gl_GlobalInvocationID.xy;
    if (xy.x >= pc.size || xy.y >= pc.size) return;
    float nf = float(pc.size);
    uint i = xy.y * pc.size + xy.x;
    vec4 p4 = pos.v[i];
    if (p4.w == 0.0) {
        diffuse.v[i] = vec4(0.0);
        return;
    }
    vec3 po = p4.xyz;
    vec4 eo = irr.v[i];
    vec3 a = dpdu.v[i].xyz;
    vec3 b = dpdv.v[i].xyz;
    vec3 nn = nrm.v[i].xyz;
    vec3 t1 = a - nn * dot(nn, a);
    float t1l = length(t1);
    t1 = t1l > 0.0 ? t1 / t1l : vec3(0.0);
    vec3 t2 = cross(nn, t1);
    float aa = dot(a, a), ab = dot(a, b), bb = dot(b, b);
    float det = aa * bb - ab * ab;
    if (!(det > 1e-20 * aa * bb) || t1l == 0.0) {
        diffuse.v[i] = vec4(pc.k.rgb * eo.rgb, 0.0);
        return;
    }
    float r00 = dot(a, t1), r01 = dot(a, t2), r10 = dot(b, t1), r11 = dot(b, t2);
    float m00 = (bb * r00 - ab * r10) / det;
    float m01 = (bb * r01 - ab * r11) / det;
    float m10 = (-ab * r00 + aa * r10) / det;
    float m11 = (-ab * r01 + aa * r11) / det;
    float texel_mm = sqrt(length(cross(a, b))) / nf;
    float x = float(xy.x), y = float(xy.y);
    vec4 outv = vec4(0.0);
    uint accepted_all = 0u;
    vec3 k3 = pc.k.rgb;
    outv.r = channel(0u, i, x, y, nf, po, eo.r, k3.r, m00, m01, m10, m11, texel_mm, accepted_all);
    outv.g = channel(1u, i, x, y, nf, po, eo.g, k3.g, m00, m01, m10, m11, texel_mm, accepted_all);
    outv.b = channel(2u, i, x, y, nf, po, eo.b, k3.b, m00, m01, m10, m11, texel_mm, accepted_all);
    outv.a = float(accepted_all) / float(3u * pc.samples);
    diffuse.v[i] = outv;
}
