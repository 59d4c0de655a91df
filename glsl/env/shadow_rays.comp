#version 450
// Pass `env shadow_rays`: the caps' split of the light corrected per lobe by the rays of
// pass `env trace`. The method: glsl/env/shadow.glsl.
#define ENV_RAYS 1
#include <env/shadow.glsl>
