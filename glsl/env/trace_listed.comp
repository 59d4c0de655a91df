#version 450
// Pass `env trace` over this frame's vertex list (glsl/env/listed.glsl). The method:
// glsl/env/trace.glsl.
#define ENV_LISTED 1
#include <env/trace.glsl>
