#version 450
// Pass `env shadow_rays` over this frame's vertex list (glsl/env/listed.glsl). The
// method: glsl/env/shadow.glsl.
#define ENV_RAYS 1
#define ENV_LISTED 1
#include <env/shadow.glsl>
