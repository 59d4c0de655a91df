#version 450
#include <common/util.glsl>
// Pass `sss vertex irradiance` (with a per-vertex irradiance set only): copies the caller's
// per-vertex rgb irradiance (a storage buffer, vec4 per vertex) into an image, vertex v at
// (v % VERTEX_ROW, v / VERTEX_ROW), which the irradiance pass reads three texels of per
// texel: lavapipe loads a storage buffer at a per-lane index lane by lane, component by
// component, and an image texel's four channels at once. One invocation per vertex.
layout(local_size_x = 64) in;

layout(push_constant) uniform Push {
    uint vertices;
} pc;

const uint VERTEX_ROW = 1024u;

layout(std430, set = 0, binding = 0) readonly buffer Venv { vec4 v[]; } venv;
layout(set = 0, binding = 1, rgba32f) writeonly uniform image2D venv_texels;

void main() {
    uint v = gl_GlobalInvocationID.x;
    if (v >= pc.vertices) return;
    imageStore(venv_texels, table_texel(v, VERTEX_ROW), venv.v[v]);
}
