#version 450
// Pass `btf env vertices` over the kernel's static vertex list (glsl/btf/env_vertices.glsl).
#include "env_vertices.glsl"
