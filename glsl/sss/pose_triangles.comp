#version 450
// Per-frame geometry of a skinned mesh, step 2 (pass `sss pose triangles`): per triangle, from
// the vertex frames of this pose (`vframes`, mm) and the topology fixed by the UV layout
// (`walk_topo`: corners, neighbours, UVs; src/kernels/sss/posed.rs walk_topology):
// - the surface walk's record (src/kernels/sss/walk.rs SurfaceWalk::records, read by the
//   diffusion): the triangle's 2D frame (1 / l1, x2, 1 / y2), the edge kinds, its UV map, and
//   per shared edge the map from its barycentrics to the atlas through the neighbour unfolded
//   about that edge into its plane (a rotation, or a reflection where the two are wound
//   inconsistently);
// - `trirec`: its unit face normal and texel area |e1 x e2| / |det| (det: the UV area in
//   texel units, fixed), for pass `sss pose texels`.
// f32 throughout; the rotation is taken from the edge's two 2D directions (dot and cross)
// where the CPU (walk.rs unfold_map) goes through atan2: equal up to rounding.
#extension GL_EXT_control_flow_attributes : require
layout(local_size_x = 64) in;

layout(push_constant) uniform Push {
    uint triangles;
} pc;

const uint WALK_ROW = 1024u;   // pack::BVH_ROW
const uint WALK_RECORD = 9u;   // walk::RECORD_TEXELS
const uint TOPOLOGY = 4u;      // posed::TOPOLOGY_TEXELS
const uint EDGE_SHARED = 0u;   // walk::EDGE_*
const uint EDGE_LOST = 2u;

// The vertex frames (position mm, normal), vertex v at texels 2v, 2v + 1 (pass `sss pose
// vertices`).
layout(set = 0, binding = 0, rgba32f) readonly uniform image2D vframes;
// TOPOLOGY texels a triangle, WALK_ROW a row (an image: lavapipe loads a texel with one
// vector gather, a storage buffer's uvec4 at a per-lane index with a loop over the lanes per
// component).
layout(set = 0, binding = 1, rgba32ui) readonly uniform uimage2D walk_topo;
layout(set = 0, binding = 2, rgba32ui) writeonly uniform uimage2D walk;
layout(set = 0, binding = 3, rgba32f) writeonly uniform image2D trirec;

struct Tri {
    vec3 p[3];
    vec3 x;      // frame axes (zero when degenerate)
    vec3 y;
    vec3 shape;  // l1, x2, y2 (zero when degenerate)
};

// Texel k of the topology.
uvec4 topo(uint k) {
    return imageLoad(walk_topo, ivec2(k % WALK_ROW, k / WALK_ROW));
}

vec3 vload(uint k) {
    return imageLoad(vframes, ivec2(k % WALK_ROW, k / WALK_ROW)).xyz;
}

Tri load(uint t) {
    uvec4 c = topo(TOPOLOGY * t);
    Tri r;
    r.p[0] = vload(2u * c.x);
    r.p[1] = vload(2u * c.y);
    r.p[2] = vload(2u * c.z);
    vec3 e1 = r.p[1] - r.p[0];
    vec3 e2 = r.p[2] - r.p[0];
    float l1 = length(e1);
    vec3 n = cross(e1, e2);
    float ln = length(n);
    if (!(l1 > 0.0) || !(ln > 0.0)) {
        r.x = vec3(0.0);
        r.y = vec3(0.0);
        r.shape = vec3(0.0);
        return r;
    }
    r.x = e1 / l1;
    r.y = cross(n / ln, r.x);
    r.shape = vec3(l1, dot(e2, r.x), dot(e2, r.y));
    return r;
}

vec2 to2(Tri f, vec3 q) {
    vec3 d = q - f.p[0];
    return vec2(dot(d, f.x), dot(d, f.y));
}

// The edge map (cos, sin, tx, ty) applied to a point or (translate = false) a vector;
// flip: y is negated after the rotation.
vec2 apply(vec4 m, bool flip, vec2 q, bool translate) {
    float f = flip ? -1.0 : 1.0;
    vec2 t = translate ? m.zw : vec2(0.0);
    return vec2(m.x * q.x - m.y * q.y + t.x, f * (m.y * q.x + m.x * q.y) + t.y);
}

float cross2(vec2 u, vec2 w) {
    return u.x * w.y - u.y * w.x;
}

// The rotation (cos, sin) turning direction a onto direction b.
vec2 turn(vec2 a, vec2 b) {
    float l = length(a) * length(b);
    return l > 0.0 ? vec2(dot(a, b), cross2(a, b)) / l : vec2(1.0, 0.0);
}

void main() {
    uint t = gl_GlobalInvocationID.x;
    if (t >= pc.triangles) return;
    uvec4 c = topo(TOPOLOGY * t);
    uvec4 nb = topo(TOPOLOGY * t + 1u);
    uvec4 uva = topo(TOPOLOGY * t + 2u);
    uvec4 uvb = topo(TOPOLOGY * t + 3u);
    Tri a = load(t);
    bool a_ok = a.shape.x > 0.0 && a.shape.z > 0.0;
    float il1 = a_ok ? 1.0 / a.shape.x : 0.0;
    float iy2 = a_ok ? 1.0 / a.shape.z : 0.0;
    uint kinds = 0u;
    uvec4 rec[6];
    // Unrolled, and the neighbour's far corner picked by selects: the record slots and the
    // corners are then read and written at constant indices, in registers rather than
    // per-lane memory (lavapipe; `bench frame`, 4 alternated runs twice: 0.41 -> 0.37 and
    // 0.43 -> 0.39 ms).
    [[unroll]] for (uint k = 0u; k < 3u; k++) {
        uint cls = (c.w >> (2u * k)) & 3u;
        vec4 v = vec4(0.0);
        vec2 s = vec2(0.0);
        if (cls == EDGE_SHARED) {
            uint n = nb[k];
            Tri b = load(n);
            bool b_ok = b.shape.x > 0.0 && b.shape.z > 0.0;
            if (!b_ok) cls = EDGE_LOST;
            uint j = (nb.w >> (2u * k)) & 3u;
            vec3 ea = a.p[(k + 1u) % 3u], eb = a.p[(k + 2u) % 3u];
            vec2 a_t = to2(a, ea), b_t = to2(a, eb), c_t = to2(a, a.p[k]);
            vec2 a_n = to2(b, ea), b_n = to2(b, eb), c_n = to2(b, j == 0u ? b.p[0] : (j == 1u ? b.p[1] : b.p[2]));
            vec2 dt = b_t - a_t, dn = b_n - a_n;
            vec4 m = vec4(0.0);
            bool flip = false;
            bool found = false;
            for (uint fi = 0u; fi < 2u && !found; fi++) {
                bool fl = fi == 1u;
                vec2 target = vec2(dn.x, fl ? -dn.y : dn.y);
                vec2 cs = turn(dt, target);
                vec4 mm = vec4(cs, 0.0, 0.0);
                vec2 tr = a_n - apply(mm, fl, a_t, false);
                mm.zw = tr;
                if (cross2(dn, apply(mm, fl, c_t, true) - a_n) * cross2(dn, c_n - a_n) <= 0.0) {
                    m = mm;
                    flip = fl;
                    found = true;
                }
            }
            if (!found) {
                vec2 cs = turn(dt, dn);
                m = vec4(cs, 0.0, 0.0);
                m.zw = a_n - apply(m, false, a_t, false);
                flip = false;
            }
            if (b_ok) {
                // This triangle's barycentrics (b1, b2) -> its 2D point -> the neighbour's
                // frame -> the neighbour's barycentrics -> the atlas through its UV map.
                uvec4 nuva = topo(TOPOLOGY * n + 2u);
                uvec4 nuvb = topo(TOPOLOGY * n + 3u);
                vec2 uv0 = uintBitsToFloat(nuva.xy);
                vec2 du1 = uintBitsToFloat(nuva.zw), du2 = uintBitsToFloat(nuvb.xy);
                float m1 = b.shape.x, mx2 = b.shape.y, my2 = b.shape.z;
                // The translation (b1 = b2 = 0), then the linear part per unit b1 and b2.
                vec2 q0 = m.zw;
                float g2 = q0.y / my2;
                float g1 = (q0.x - mx2 * g2) / m1;
                s = uv0 + du1 * g1 + du2 * g2;
                vec2 q1 = apply(m, flip, vec2(a.shape.x, 0.0), false);
                g2 = q1.y / my2;
                g1 = (q1.x - mx2 * g2) / m1;
                vec2 e1 = du1 * g1 + du2 * g2;
                vec2 q2 = apply(m, flip, vec2(a.shape.y, a.shape.z), false);
                g2 = q2.y / my2;
                g1 = (q2.x - mx2 * g2) / m1;
                vec2 e2 = du1 * g1 + du2 * g2;
                v = vec4(e1.x, e2.x, e1.y, e2.y);
            }
        }
        kinds |= cls << (2u * k);
        rec[2u * k] = floatBitsToUint(v);
        rec[2u * k + 1u] = uvec4(floatBitsToUint(s), 0u, 0u);
    }
    uint base = t * WALK_RECORD;
    uvec4 head = uvec4(floatBitsToUint(il1), floatBitsToUint(a.shape.y), floatBitsToUint(iy2), kinds);
    imageStore(walk, ivec2(base % WALK_ROW, base / WALK_ROW), head);
    uint i1 = base + 1u, i2 = base + 2u;
    imageStore(walk, ivec2(i1 % WALK_ROW, i1 / WALK_ROW), uva);
    // z: the triangle's skin region, fixed (posed::walk_topology; pack::region_records).
    imageStore(walk, ivec2(i2 % WALK_ROW, i2 / WALK_ROW), uvec4(uvb.xy, uvb.w, 0u));
    [[unroll]] for (uint r = 0u; r < 6u; r++) {
        uint i = base + 3u + r;
        imageStore(walk, ivec2(i % WALK_ROW, i / WALK_ROW), rec[r]);
    }
    // Face normal and texel area.
    vec3 fn = cross(a.p[1] - a.p[0], a.p[2] - a.p[0]);
    float ln = length(fn);
    float det = abs(uintBitsToFloat(uvb.z));
    imageStore(trirec, ivec2(t % WALK_ROW, t / WALK_ROW),
        vec4(ln > 0.0 ? fn / ln : vec3(0.0), det > 0.0 ? ln / det : 0.0));
}
