#version 450
// Pass `compose background value`: one invocation takes the frame's background pixel as the
// compose pass stores it (glsl/compose/output.glsl: the background colour, alpha 0, the
// frame's exposure) and writes the indirect arguments of pass `compose background`
// (glsl/compose/background.comp): every pixel if the pixel differs from the previous
// frame's (or was never stored), else none. The tone mapping runs once a frame, and the
// background is stored only on frames when it changed.
layout(local_size_x = 1) in;
#define COMPOSE_NO_OUTPUT 1
#include <compose/output.glsl>

// Zero when the kernel is made: no pixel stored.
layout(std430, set = 0, binding = 16) buffer State { Background s; } bg;

// glsl/compose/background.comp: quads of 4 pixels a dispatch row, 64 invocations a group.
const uint ROW = 4096u;

void main() {
    Params P = params.p;
    Background b = bg.s;
    vec3 r = max(P.background.rgb, vec3(0.0));
    vec4 h = vec4(r, 0.0);
    uint l = ldr_word(r, P.eye.w);
    bool same = b.stored != 0u && floatBitsToUint(h) == floatBitsToUint(b.hdr) && l == b.ldr;
    uint quads = (P.counts.x * P.counts.y + 3u) / 4u;
    uvec2 groups = uvec2((min(quads, ROW) + 63u) / 64u, (quads + ROW - 1u) / ROW);
    b.dispatch = same ? uvec4(0u, 1u, 1u, 0u) : uvec4(groups, 1u, 0u);
    b.hdr = h;
    b.ldr = l;
    b.stored = 1u;
    bg.s = b;
}
