#version 450
// Pass `env trace` over every vertex. The method: glsl/env/trace.glsl.
#include <env/trace.glsl>
