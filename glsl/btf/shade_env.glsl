// `btf env`: cloth under the SG environment, included by btf/shade_env_{rows,layers,block}.comp
// (BTF_MODE 1, 0, 2 as for `btf shade`, whose textures, map and G-buffer it binds). Per
// covered pixel: the lobes into the tangent frame, the light factor c_i of each of the 81
// light directions (src/kernels/btf/env.rs: midpoint rule on 2 x 2 sub-cells for broad
// lobes, a splat of the lobe's own 8 x 12-point quadrature into the cells for sharp ones),
// then sum_i c_i x (the BTF at light i, view-interpolated by 3 taps), ADDED to `result`
// (the pass runs after `btf shade`, which wrote the directional lights there).
// The sampling code (footprint, tap, lookup) is that of common/btf_shade.glsl.
layout(local_size_x = 16, local_size_y = 4) in;

layout(push_constant) uniform Push {
    vec4 camera;        // xyz: camera position; w = 0: xyz is the direction towards an
                        // orthographic camera instead
    uvec4 dims;         // width, height, lobes J, layers per array
    uvec4 layout_info;  // x: gutter; y: tile width; z: layer width; w: tile height
    uvec4 env;          // x: 1 when `visibility` holds V_j per pixel and lobe
} pc;

#if BTF_MODE == 2
layout(set = 0, binding = 0) uniform utexture2DArray btf_blocks;
#else
layout(set = 0, binding = 0) uniform texture2DArray btf[4];
layout(set = 0, binding = 1) uniform sampler tile_sampler;   // linear, repeat
#endif
layout(set = 0, binding = 2) uniform utexture2D dir_map;
layout(set = 0, binding = 4) uniform texture2DArray gbuffer;
layout(std430, set = 0, binding = 5) buffer Result { vec4 v[]; } result;
// Two vec4 per lobe: (axis xyz world, sharpness), (amplitude rgb, 0).
layout(std430, set = 0, binding = 6) readonly buffer Lobes { vec4 v[]; } lobes;
// V_j per pixel: [pixel * J + j] (read only when pc.env.x == 1).
layout(std430, set = 0, binding = 7) readonly buffer Visibility { float v[]; } visibility;
// Midpoint-rule points: per cell SUB^2 x (direction xyz tangent, solid angle).
layout(std430, set = 0, binding = 8) readonly buffer Cells { vec4 v[]; } cells;

const float PI = 3.14159265358979;
const float TAU = 6.28318530717959;
const uint CELLS = 81u;
const uint SUB2 = 4u;            // env.rs MIDPOINT_SUB^2
const float LAM_SPLAT = 24.0;    // env.rs LAM_SPLAT
const uint SPLAT_RINGS = 8u;     // env.rs SPLAT_RINGS
const uint SPLAT_AZIMUTHS = 12u; // env.rs SPLAT_AZIMUTHS
const uint RING_START[6] = uint[6](0u, 1u, 7u, 19u, 37u, 57u);
const uint RING_N[6] = uint[6](1u, 6u, 12u, 18u, 20u, 24u);
const float COS_BOUNDS[5] = float[5](0.9914449, 0.9238795, 0.7933533, 0.6087614, 0.3826834);

#if BTF_MODE == 2
struct Footprint {
    ivec2 block;
    uvec4 shift;
    bvec4 hi;
    vec4 weight;
};

Footprint footprint(vec2 uv) {
    vec2 size = vec2(pc.layout_info.y, pc.layout_info.w);
    vec2 xy = fract(uv) * size - 0.5;
    vec2 f = floor(xy);
    vec2 fr = xy - f;
    ivec2 xe = ivec2(f) + 1;
    Footprint p;
    p.block = xe / 3;
    ivec2 o = xe - 3 * p.block;
    uint s0 = uint(16 * (o.y & 1) + 4 * o.x);
    uint s1 = uint(16 * ((o.y + 1) & 1) + 4 * o.x);
    p.shift = uvec4(s0, s0 + 4u, s1, s1 + 4u);
    p.hi = bvec4(o.y >= 2, o.y >= 2, o.y + 1 >= 2, o.y + 1 >= 2);
    p.weight = vec4((1.0 - fr.x) * (1.0 - fr.y), fr.x * (1.0 - fr.y),
                    (1.0 - fr.x) * fr.y, fr.x * fr.y);
    return p;
}

vec3 endpoint(uint e) {
    return vec3(e & 0x7FFu, (e >> 11u) & 0x7FFu, e >> 22u)
         * vec3(1.0 / 2047.0, 1.0 / 2047.0, 1.0 / 1023.0);
}

vec3 tap(uint view, uint light, Footprint p) {
    int blocks_x = int(pc.layout_info.z / 81u);
    uvec4 q = texelFetch(btf_blocks,
                         ivec3(p.block.x + int(light) * blocks_x, p.block.y, int(view)), 0);
    uvec4 word = uvec4(p.hi.x ? q.w : q.z, p.hi.y ? q.w : q.z,
                       p.hi.z ? q.w : q.z, p.hi.w ? q.w : q.z);
    vec4 idx = vec4((word >> p.shift) & 15u);
    vec3 e0 = endpoint(q.x);
    return e0 + (endpoint(q.y) - e0) * (dot(p.weight, idx) * (1.0 / 15.0));
}
#else
struct Footprint {
    vec2 uv;
};

Footprint footprint(vec2 uv) {
    return Footprint(uv);
}

vec3 tap(uint view, uint light, Footprint p) {
    vec2 uv = p.uv;
#if BTF_MODE == 1
    float w = float(pc.layout_info.y);
    float g = float(pc.layout_info.x);
    float x = float(light) * (w + 2.0 * g) + g + fract(uv.x) * w;
    return textureLod(sampler2DArray(btf[0], tile_sampler),
                      vec3(x / float(pc.layout_info.z), uv.y, float(view)), 0.0).rgb;
#else
    uint slice = view * 81u + light;
    uint a = slice / pc.dims.w;
    vec3 c = vec3(uv, float(slice - a * pc.dims.w));
    if (a == 0u) return textureLod(sampler2DArray(btf[0], tile_sampler), c, 0.0).rgb;
    if (a == 1u) return textureLod(sampler2DArray(btf[1], tile_sampler), c, 0.0).rgb;
    if (a == 2u) return textureLod(sampler2DArray(btf[2], tile_sampler), c, 0.0).rgb;
    return textureLod(sampler2DArray(btf[3], tile_sampler), c, 0.0).rgb;
#endif
}
#endif

void lookup(vec3 d, out uvec3 index, out vec3 weight) {
    ivec2 n = textureSize(dir_map, 0);
    vec2 p = d.xy / (1.0 + d.z);
    ivec2 t = clamp(ivec2(floor((p + 1.0) * 0.5 * vec2(n))), ivec2(0), n - 1);
    uvec4 m = texelFetch(dir_map, t, 0);
    index = uvec3(m.x & 0xFFu, (m.x >> 8u) & 0xFFu, (m.x >> 16u) & 0xFFu);
    weight = uintBitsToFloat(m.yzw);
}

// The cell of tangent-space unit direction d (z > 0), as env.rs cell_of.
uint cell_of(vec3 d) {
    uint ring = 0u;
    for (uint r = 0u; r < 5u; r++) {
        if (d.z < COS_BOUNDS[r]) ring = r + 1u;
    }
    uint n = RING_N[ring];
    if (n == 1u) return 0u;
    float x = atan(d.y, d.x) * (float(n) / TAU) + 0.5;
    int s = int(floor(x));
    if (s < 0) s += int(n);
    if (s >= int(n)) s -= int(n);
    return RING_START[ring] + uint(s);
}

vec3 c[CELLS];

// Adds scale x W_i of a unit lobe (tangent axis a, sharpness lam) to c (env.rs lobe_weights).
void add_lobe(vec3 a, float lam, vec3 scale) {
    if (lam <= LAM_SPLAT) {
        for (uint i = 0u; i < CELLS; i++) {
            float w = 0.0;
            for (uint s = 0u; s < SUB2; s++) {
                vec4 q = cells.v[i * SUB2 + s];
                float cosw = a.x * q.x + a.y * q.y + a.z * q.z;
                w += q.w * exp(lam * (cosw - 1.0));
            }
            c[i] += scale * w;
        }
        return;
    }
    float tail = 1.0 - exp(-2.0 * lam);
    float weight = TAU * tail / lam / float(SPLAT_RINGS * SPLAT_AZIMUTHS);
    float sgn = a.z >= 0.0 ? 1.0 : -1.0;
    float ia = -1.0 / (sgn + a.z);
    float b = a.x * a.y * ia;
    vec3 e1 = vec3(1.0 + sgn * a.x * a.x * ia, sgn * b, -sgn * a.x);
    vec3 e2 = vec3(b, sgn + a.y * a.y * ia, -a.y);
    vec3 add = scale * weight;
    for (uint k = 0u; k < SPLAT_RINGS; k++) {
        float q = (float(k) + 0.5) / float(SPLAT_RINGS);
        float u = -log(1.0 - q * tail) / lam;
        float cos_t = 1.0 - u;
        float sin_t = sqrt(max(u * (2.0 - u), 0.0));
        for (uint m = 0u; m < SPLAT_AZIMUTHS; m++) {
            float phi = TAU * (float(m) + 0.5 * float(k & 1u)) / float(SPLAT_AZIMUTHS);
            float s = sin(phi) * sin_t;
            float co = cos(phi) * sin_t;
            vec3 d = vec3(cos_t * a.x + co * e1.x + s * e2.x,
                          cos_t * a.y + co * e1.y + s * e2.y,
                          cos_t * a.z + co * e1.z + s * e2.z);
            if (d.z > 0.0) c[cell_of(d)] += add;
        }
    }
}

void main() {
    uvec2 px = gl_GlobalInvocationID.xy;
    if (any(greaterThanEqual(px, pc.dims.xy))) return;
    uint k = px.y * pc.dims.x + px.x;
    vec4 g0 = texelFetch(gbuffer, ivec3(px, 0), 0);
    if (abs(g0.w) < 0.5) return;
    vec4 g1 = texelFetch(gbuffer, ivec3(px, 1), 0);
    vec4 g2 = texelFetch(gbuffer, ivec3(px, 2), 0);
    vec3 n = normalize(g1.xyz);
    vec3 t = normalize(g2.xyz - n * dot(n, g2.xyz));
    vec3 bt = (g0.w < 0.0 ? -1.0 : 1.0) * cross(n, t);
    vec3 view = pc.camera.w == 0.0 ? pc.camera.xyz : normalize(pc.camera.xyz - g0.xyz);
    vec3 vt = vec3(dot(view, t), dot(view, bt), dot(view, n));
    if (vt.z <= 0.0) return;
    for (uint i = 0u; i < CELLS; i++) c[i] = vec3(0.0);
    uint J = pc.dims.z;
    for (uint j = 0u; j < J; j++) {
        vec4 p = lobes.v[2u * j];
        vec3 amp = lobes.v[2u * j + 1u].rgb;
        float v = pc.env.x == 1u ? visibility.v[k * J + j] : 1.0;
        vec3 a = vec3(dot(p.xyz, t), dot(p.xyz, bt), dot(p.xyz, n));
        add_lobe(a, p.w, amp * (v * (1.0 / PI)));
    }
    uvec3 iv;
    vec3 wv;
    lookup(vt, iv, wv);
    Footprint fp = footprint(vec2(g1.w, g2.w));
    vec3 sum = vec3(0.0);
    for (uint i = 0u; i < CELLS; i++) {
        if (all(equal(c[i], vec3(0.0)))) continue;
        vec3 row = vec3(0.0);
        for (int a = 0; a < 3; a++) row += wv[a] * tap(iv[a], i, fp);
        sum += c[i] * row;
    }
    result.v[k] += vec4(sum, 0.0);
}
