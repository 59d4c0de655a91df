#version 450
// Pass `env shadow`: the caps' split of the light scaled by a per-vertex visibility (AO's).
// The method: glsl/env/shadow.glsl.
#include <env/shadow.glsl>
