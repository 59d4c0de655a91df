#version 450
// Gather-rate probe for `bench peak`: `loads` vec4 loads per invocation from a storage
// buffer (mode bit 1 clear) or an rgba32f storage image (bit 1 set) of 2^k vec4s.
// Coherent (bit 0 clear): invocation i reads element i + 64 k at step k (neighbouring lanes,
// neighbouring elements); random (bit 0 set): a hashed element each step.
#include <common/util.glsl>
layout(local_size_x = 256) in;

layout(push_constant) uniform Push {
    uint n;       // invocations
    uint loads;   // loads per invocation
    uint mode;    // bit 0: random, bit 1: storage image
    uint bits;    // log2 of the element count
    uint width_bits;  // log2 of the image's width
} pc;

layout(std430, set = 0, binding = 0) readonly buffer Src { vec4 v[]; } src;
layout(set = 0, binding = 1, rgba32f) readonly uniform image2D img;
layout(std430, set = 0, binding = 2) writeonly buffer Dst { vec4 v[]; } dst;

void main() {
    uint i = linear_id();
    if (i >= pc.n) return;
    uint mask = (1u << pc.bits) - 1u;
    uint wmask = (1u << pc.width_bits) - 1u;
    uint h = hash_u32(i);
    bool random = (pc.mode & 1u) != 0u;
    bool image = (pc.mode & 2u) != 0u;
    vec4 sum = vec4(0.0);
    for (uint k = 0u; k < pc.loads; k++) {
        uint e;
        if (random) {
            h = h * 1664525u + 1013904223u;
            e = h >> (32u - pc.bits);
        } else {
            e = (i + 64u * k) & mask;
        }
        if (image) {
            sum += imageLoad(img, ivec2(e & wmask, e >> pc.width_bits));
        } else {
            sum += src.v[e];
        }
    }
    dst.v[i] = sum;
}
