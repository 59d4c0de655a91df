#version 450
// Texture-space irradiance: E per texel from directional and point lights, E =
// sum_l strength_l max(n.l, 0) V_l, with the texel's own normal, position (point-light
// distance) and cosine, and the visibility V_l interpolated over the texel's triangle from
// the per-vertex shadow rays of pass `sss vertex light` (glsl/sss/vertex_light.comp) with the
// texel centre's barycentrics. White lights: E is written to rgb alike. Transmission (mode
// != 0): the per-vertex (rgb, thickness) interpolated the same way. Shadow boundaries are
// therefore resolved at the mesh's vertex spacing, not per texel (the difference is measured
// by `vkshade sss`, report.json shadowing). The CPU twin is src/kernels/sss/cpu.rs.
layout(local_size_x = 8, local_size_y = 8) in;

layout(push_constant) uniform Push {
    uint size;     // texture is size x size
    uint lights;
    uint mode;     // transmission: 0 off, else on
} pc;

layout(std430, set = 0, binding = 0) readonly buffer Pos { vec4 v[]; } pos;       // xyz, flag
layout(std430, set = 0, binding = 1) readonly buffer Nrm { vec4 v[]; } nrm;       // xyz, area
layout(std430, set = 0, binding = 2) readonly buffer TexelTri { uvec4 v[]; } texel_tri;
layout(std430, set = 0, binding = 3) readonly buffer TriIdx { uvec4 v[]; } tri_idx;
layout(std430, set = 0, binding = 4) readonly buffer Lights { vec4 v[]; } lights; // 2 per light
layout(std430, set = 0, binding = 5) readonly buffer Vis { uint v[]; } vis;
layout(std430, set = 0, binding = 6) readonly buffer Vtrans { vec4 v[]; } vtrans;
layout(std430, set = 0, binding = 7) writeonly buffer Irr { vec4 v[]; } irr;
layout(std430, set = 0, binding = 8) writeonly buffer Trans { vec4 v[]; } trans; // rgb, t
// A copy of irr for the diffusion's gathers (one texel fetch per sample on lavapipe).
layout(set = 0, binding = 9, rgba32f) writeonly uniform image2D irr_img;

void main() {
    uvec2 xy = gl_GlobalInvocationID.xy;
    if (xy.x >= pc.size || xy.y >= pc.size) return;
    uint i = xy.y * pc.size + xy.x;
    vec4 p4 = pos.v[i];
    if (p4.w == 0.0) {
        irr.v[i] = vec4(0.0);
        trans.v[i] = vec4(0.0);
        imageStore(irr_img, ivec2(xy), vec4(0.0));
        return;
    }
    vec3 p = p4.xyz;
    vec3 n = nrm.v[i].xyz;
    uvec4 tt = texel_tri.v[i];
    float w1 = uintBitsToFloat(tt.y), w2 = uintBitsToFloat(tt.z);
    float w0 = 1.0 - w1 - w2;
    uvec3 ids = tri_idx.v[tt.x].xyz;
    uint b0 = vis.v[ids.x], b1 = vis.v[ids.y], b2 = vis.v[ids.z];
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
        // Exactly 0 or 1 when the corners agree (the barycentrics' sum may round off 1).
        float v = (c0 == c1 && c1 == c2) ? float(c0)
            : w0 * float(c0) + w1 * float(c1) + w2 * float(c2);
        e += strength * c * v;
    }
    irr.v[i] = vec4(e, e, e, 1.0);
    imageStore(irr_img, ivec2(xy), vec4(e, e, e, 1.0));
    vec4 tr = vec4(0.0);
    if (pc.mode != 0u) {
        tr = w0 * vtrans.v[ids.x] + w1 * vtrans.v[ids.y] + w2 * vtrans.v[ids.z];
    }
    trans.v[i] = tr;
}
