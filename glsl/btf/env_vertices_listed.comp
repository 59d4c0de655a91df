#version 450
// Pass `btf env vertices` over a vertex list written on the GPU this frame, dispatched
// indirectly (glsl/btf/env_vertices.glsl, ENV_VERTICES_LISTED).
#define ENV_VERTICES_LISTED 1
#include "env_vertices.glsl"
