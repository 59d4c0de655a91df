#version 450
// Pass `compose background value`: one invocation stores the background pixel as the compose
// pass stores it (glsl/compose/output.glsl: the background colour, alpha 0, the frame's
// exposure) into pixel 0 of a one-pixel HDR and LDR pair, which pass `compose background`
// (glsl/compose/background.comp) copies to every pixel: the tone mapping runs once a frame
// instead of once a pixel.
layout(local_size_x = 1) in;
#define hdr bg_hdr
#define ldr bg_ldr
#include <compose/output.glsl>

void main() {
    Params P = params.p;
    store_pixel(0u, P.background.rgb, 0.0, P.eye.w);
}
