// The light side of the BTF light basis (src/kernels/btf/basis.rs), shared by `btf env basis`
// (per pixel) and `btf env vertices` (per cloth vertex): each lobe's axis in a tangent frame,
// octahedrally encoded, selects its RANK basis weights Q_jk in the lobe's table (2 filtered
// fetches), summed into L_k. The includer declares `table` and `table_sampler`.
#ifndef VKSHADE_BTF_BASIS_LIGHT_GLSL
#define VKSHADE_BTF_BASIS_LIGHT_GLSL

const uint RANK = 8u;   // basis.rs RANK
const uint LAYERS_PER_LOBE = 2u;
const float PI = 3.14159265358979;

// The per-vertex light factors `btf env vertices` writes and `btf env basis` reads (mode 3):
// LIGHT_TEXELS rgba32f texels per vertex, LIGHT_VERTICES vertices a row of the image
// (kernels::btf::gpu::{LIGHT_TEXELS, LIGHT_VERTICES}): texels 0..5 the front face's L_k
// (scalar s = 3 k + channel at texel s / 4, component s % 4), 6..11 the back face's (the
// G-buffer's frame there has the normal negated: the lobe's z negated), 12 the unit normal.
const uint LIGHT_TEXELS = 13u;
const uint LIGHT_VERTICES = 256u;
const uint LIGHT_BACK = 6u;
const uint LIGHT_NORMAL = 12u;

ivec2 light_texel(uint v, uint i) {
    return ivec2((v % LIGHT_VERTICES) * LIGHT_TEXELS + i, v / LIGHT_VERTICES);
}

float sgn(float x) {
    return x >= 0.0 ? 1.0 : -1.0;
}

// basis.rs oct_encode.
vec2 oct_encode(vec3 d) {
    float s = abs(d.x) + abs(d.y) + abs(d.z);
    vec2 p = d.xy / s;
    if (d.z < 0.0) p = vec2((1.0 - abs(p.y)) * sgn(p.x), (1.0 - abs(p.x)) * sgn(p.y));
    return p * 0.5 + 0.5;
}

// L_k += s Q_jk(local), lobe j's axis `local` in the tangent frame.
void add_lobe(inout vec3 l[RANK], vec3 s, vec3 local, uint j) {
    vec2 uv = oct_encode(local);
    vec4 q0 = textureLod(sampler2DArray(table, table_sampler),
                         vec3(uv, float(LAYERS_PER_LOBE * j)), 0.0);
    vec4 q1 = textureLod(sampler2DArray(table, table_sampler),
                         vec3(uv, float(LAYERS_PER_LOBE * j + 1u)), 0.0);
    l[0] += s * q0.x;
    l[1] += s * q0.y;
    l[2] += s * q0.z;
    l[3] += s * q0.w;
    l[4] += s * q1.x;
    l[5] += s * q1.y;
    l[6] += s * q1.z;
    l[7] += s * q1.w;
}

#endif
