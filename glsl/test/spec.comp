#version 450
// Test kernel for specialization constants: out[i] = FACTOR * i + OFFSET, with a workgroup
// size that can be specialised too (constant id 3, default 64).
layout(local_size_x = 64, local_size_x_id = 3) in;
layout(constant_id = 0) const uint FACTOR = 2u;
layout(constant_id = 7) const float OFFSET = 0.5;
layout(push_constant) uniform Push { uint n; } pc;
layout(std430, set = 0, binding = 0) writeonly buffer Out { float v[]; } outbuf;
void main() {
    uint i = gl_GlobalInvocationID.x;
    if (i < pc.n) outbuf.v[i] = float(FACTOR * i) + OFFSET;
}
