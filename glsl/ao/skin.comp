#version 450
#include <common/util.glsl>
// Linear-blend skinning of the sphere-tree centres (radii are rigid), with the frame's joint
// matrices (the pose kernel's; the vertices are posed there). Each node also gets its
// extent: the farthest reach of its skinned leaf spheres from its own skinned centre (a
// leaf's extent is its radius), computed by the node itself so that no second pass is needed.
layout(local_size_x = 64) in;

layout(push_constant) uniform Push {
    uint sphere_count;
    uint branch;
    uint first_leaf;
} pc;

layout(std430, set = 0, binding = 0) readonly buffer Joints { mat4 m[]; } joints;
layout(std430, set = 0, binding = 1) readonly buffer RestSpheres { vec4 s[]; } rest_sph;
layout(std430, set = 0, binding = 2) readonly buffer SphereJoints { uvec2 j[]; } sjoints;
layout(std430, set = 0, binding = 3) readonly buffer SphereWeights { vec4 w[]; } sweights;
layout(std430, set = 0, binding = 4) writeonly buffer Spheres { vec4 s[]; } sph;
layout(std430, set = 0, binding = 5) writeonly buffer Extents { float e[]; } ext;
layout(std430, set = 0, binding = 6) readonly buffer Shares { float s[]; } share;
// What `ao occlusion` walks, two texels a node, NODE_ROW texels a row: texel 2s the posed
// sphere (centre, radius), texel 2s + 1 (extent, child share, 0, 0). An image because
// lavapipe loads an image texel with one vector gather and a storage-buffer element at a
// per-lane address with a loop over the lanes.
layout(set = 0, binding = 7, rgba32f) uniform writeonly image2D nodes;
layout(constant_id = 0) const uint NODE_ROW = 4096u; // kernels::table_row

void store_node(uint s, vec4 sphere, float extent) {
    uint t = 2u * s;
    imageStore(nodes, table_texel(t, NODE_ROW), sphere);
    t += 1u;
    imageStore(nodes, table_texel(t, NODE_ROW), vec4(extent, share.s[s], 0.0, 0.0));
}

mat4 blend(uvec2 packed, vec4 w) {
    uvec4 j = uvec4(packed.x & 0xffffu, packed.x >> 16, packed.y & 0xffffu, packed.y >> 16);
    mat4 m = mat4(0.0);
    if (w.x != 0.0) m += joints.m[j.x] * w.x;
    if (w.y != 0.0) m += joints.m[j.y] * w.y;
    if (w.z != 0.0) m += joints.m[j.z] * w.z;
    if (w.w != 0.0) m += joints.m[j.w] * w.w;
    return m;
}

void main() {
    uint s = gl_GlobalInvocationID.x;
    if (s >= pc.sphere_count) return;
    vec4 rest = rest_sph.s[s];
    if (rest.w < 0.0) {
        sph.s[s] = rest; // unused slot stays unused
        ext.e[s] = rest.w;
        store_node(s, rest, rest.w);
        return;
    }
    mat4 m = blend(sjoints.j[s], sweights.w[s]);
    vec3 c = (m * vec4(rest.xyz, 1.0)).xyz;
    sph.s[s] = vec4(c, rest.w);
    float extent = rest.w;
    if (s < pc.first_leaf) {
        // Leaf descendants of s: [s * B^k + (B^k - 1) / (B - 1), + B^k), k levels down.
        uint first = s;
        uint count = 1u;
        while (first < pc.first_leaf) {
            first = first * pc.branch + 1u;
            count *= pc.branch;
        }
        for (uint l = first; l < first + count; ++l) {
            vec4 leaf = rest_sph.s[l];
            if (leaf.w < 0.0) continue;
            vec3 lc = (blend(sjoints.j[l], sweights.w[l]) * vec4(leaf.xyz, 1.0)).xyz;
            extent = max(extent, distance(lc, c) + leaf.w);
        }
    }
    ext.e[s] = extent;
    store_node(s, vec4(c, rest.w), extent);
}
