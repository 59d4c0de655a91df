#version 450
// Texture-space irradiance: E per texel from directional and point lights, E =
// sum_l strength_l max(n.l, 0) V_l, with the texel's own normal, position (point-light
// distance) and cosine, and the visibility V_l interpolated over the texel's triangle from
// the per-vertex shadow rays of pass `sss vertex light` (glsl/sss/vertex_light.comp) with the
// texel centre's barycentrics (exactly 0 or 1 where the three corners agree). White lights: E
// is written to rgb alike. Transmission (mode != 0): the per-vertex (rgb, thickness)
// interpolated the same way. Shadow boundaries are therefore resolved at the mesh's vertex
// spacing, not per texel (the difference is measured by `vkshade sss`, report.json
// `shadowing`). Everything per texel is an image (lavapipe fetches a texel's four channels at
// once; a storage-buffer load at a per-lane index loops over the lanes for each component).
// The CPU twin is src/kernels/sss/cpu.rs.
layout(local_size_x = 8, local_size_y = 8) in;

layout(push_constant) uniform Push {
    uint size;     // texture is size x size
    uint lights;
    uint mode;     // transmission: 0 off, else on
} pc;

const uint VERTEX_ROW = 1024u;

layout(set = 0, binding = 0, rgba32f) readonly uniform image2D pos;     // xyz, flag
layout(set = 0, binding = 1, rgba32f) readonly uniform image2D nrm;     // xyz, area
// The texel's triangle corners (vertex indices) and barycentrics w1, w2 as 16-bit fractions
// of 2^16 in w (cpu::texel_corners_packed).
layout(set = 0, binding = 2, rgba32ui) readonly uniform uimage2D corners;
layout(std430, set = 0, binding = 3) readonly buffer Lights { vec4 v[]; } lights; // 2 per light
layout(set = 0, binding = 4, r32ui) readonly uniform uimage2D vis;
layout(set = 0, binding = 5, rgba32f) readonly uniform image2D vtrans;
layout(set = 0, binding = 6, rgba32f) writeonly uniform image2D irr;
layout(set = 0, binding = 7, rgba32f) writeonly uniform image2D trans;  // rgb, t

ivec2 vertex_at(uint v) {
    return ivec2(v % VERTEX_ROW, v / VERTEX_ROW);
}

void main() {
    uvec2 xy = gl_GlobalInvocationID.xy;
    if (xy.x >= pc.size || xy.y >= pc.size) return;
    ivec2 at = ivec2(xy);
    vec4 p4 = imageLoad(pos, at);
    if (p4.w == 0.0) {
        imageStore(irr, at, vec4(0.0));
        imageStore(trans, at, vec4(0.0));
        return;
    }
    vec3 p = p4.xyz;
    vec3 n = imageLoad(nrm, at).xyz;
    uvec4 cr = imageLoad(corners, at);
    const float Q = 1.0 / 65536.0;
    float w1 = float(cr.w & 0xffffu) * Q, w2 = float(cr.w >> 16u) * Q;
    float w0 = 1.0 - w1 - w2;
    ivec2 a0 = vertex_at(cr.x), a1 = vertex_at(cr.y), a2 = vertex_at(cr.z);
    uint b0 = imageLoad(vis, a0).x, b1 = imageLoad(vis, a1).x, b2 = imageLoad(vis, a2).x;
    float e = 0.0;
    for (uint l = 0u; l < pc.lights; l++) {
        vec4 a = lights.v[2u * l];
        float strength = lights.v[2u * l + 1u].x;
        vec3 dir;
        if (a.w == 0.0) {
            dir = a.xyz;
        } else {
            vec3 dd = a.xyz - p;
            float dist = length(dd);
            dir = dd / dist;
            strength = strength / (dist * dist);
        }
        float c = dot(n, dir);
        if (c <= 0.0 || strength == 0.0) continue;
        uint c0 = (b0 >> l) & 1u, c1 = (b1 >> l) & 1u, c2 = (b2 >> l) & 1u;
        // Exactly 0 or 1 when the corners agree.
        float v = (c0 == c1 && c1 == c2) ? float(c0)
            : w0 * float(c0) + w1 * float(c1) + w2 * float(c2);
        e += strength * c * v;
    }
    imageStore(irr, at, vec4(e, e, e, 1.0));
    vec4 tr = vec4(0.0);
    if (pc.mode != 0u) {
        tr = w0 * imageLoad(vtrans, a0) + w1 * imageLoad(vtrans, a1) + w2 * imageLoad(vtrans, a2);
    }
    imageStore(trans, at, tr);
}
