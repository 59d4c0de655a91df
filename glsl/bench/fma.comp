#version 450
// Peak f32 FMA throughput: 8 independent vec4 FMA chains per invocation, so latency is
// hidden and every iteration is 8 * 4 * 2 = 64 FLOP. Multiplier and addend come from push
// constants so the compiler cannot fold the chains away; one store keeps them live.
#include <common/util.glsl>
layout(local_size_x = 256) in;

layout(push_constant) uniform Push { uint iterations; float mul; float add; } pc;
layout(std430, set = 0, binding = 0) writeonly buffer Out { vec4 result[]; } outbuf;

void main() {
    uint i = linear_id();
    float s = unit_float(hash_u32(i));
    vec4 a0 = vec4(s, s + 0.1, s + 0.2, s + 0.3);
    vec4 a1 = a0 + 0.01, a2 = a0 + 0.02, a3 = a0 + 0.03;
    vec4 a4 = a0 + 0.04, a5 = a0 + 0.05, a6 = a0 + 0.06, a7 = a0 + 0.07;
    vec4 m = vec4(pc.mul), c = vec4(pc.add);
    for (uint k = 0; k < pc.iterations; ++k) {
        a0 = fma(a0, m, c); a1 = fma(a1, m, c); a2 = fma(a2, m, c); a3 = fma(a3, m, c);
        a4 = fma(a4, m, c); a5 = fma(a5, m, c); a6 = fma(a6, m, c); a7 = fma(a7, m, c);
    }
    outbuf.result[i] = ((a0 + a1) + (a2 + a3)) + ((a4 + a5) + (a6 + a7));
}
