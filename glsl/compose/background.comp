#version 450
// Pass `compose background`, before `compose shade` (and `compose shade skin`) over the
// rasteriser's listed tiles (glsl/compose/shade_tiles.comp), dispatched indirectly with the arguments pass `compose
// background value` writes: every pixel takes the background pixel on a frame whose
// background pixel differs from the previous frame's (or on the first), and no pixel on the
// others. There the pixels outside the listed tiles already hold it: the rasteriser's list
// holds the tiles covered this frame and those covered the frame before (stale, which the
// shade pass shades empty), so a pixel left out was background at the previous frame too.
// Filling every pixel every frame cost 0.6-0.8 ms of the character frame's ~30 on lavapipe.
// One invocation fills 4 consecutive pixels (row-major over the whole image), their four
// LDR words in one uvec4 store: the LDR buffer is padded to whole uvec4s
// (kernels::compose::gpu::ldr_bytes). On lavapipe a storage-buffer store at a per-lane
// address runs one lane at a time, so 1.25 stores a pixel instead of 2 cost ~35% less
// (`bench frame`, alternated runs: 2.03 -> 1.29-1.44 ms).
// Invocation (x, y) of the dispatch takes quad y * ROW + x.
layout(local_size_x = 64) in;
#define COMPOSE_NO_OUTPUT 1
#include <compose/output.glsl>

layout(push_constant) uniform Push {
    uvec2 size;
} pc;

// glsl/compose/background_value.comp `ROW`.
const uint ROW = 4096u;

layout(std430, set = 0, binding = 11) writeonly buffer Hdr { vec4 c[]; } hdr;
layout(std430, set = 0, binding = 12) writeonly buffer Ldr { uvec4 c[]; } ldr;
layout(std430, set = 0, binding = 16) readonly buffer State { Background s; } bg;

void main() {
    uint quad = gl_GlobalInvocationID.y * ROW + gl_GlobalInvocationID.x;
    uint n = pc.size.x * pc.size.y;
    uint idx = 4u * quad;
    if (gl_GlobalInvocationID.x >= ROW || idx >= n) return;
    vec4 h = bg.s.hdr;
    hdr.c[idx] = h;
    if (idx + 1u < n) hdr.c[idx + 1u] = h;
    if (idx + 2u < n) hdr.c[idx + 2u] = h;
    if (idx + 3u < n) hdr.c[idx + 3u] = h;
    // Words past the last pixel are padding, never read.
    ldr.c[quad] = uvec4(bg.s.ldr);
}
