#version 450
// Pass `sss irradiance rays` of glsl/sss/irradiance_env.comp (Lights plus a per-vertex rgb irradiance, from the per-texel images). The method: glsl/sss/irradiance.glsl.
#define SSS_ENV 1
#define SSS_RAYS 1
#include <sss/irradiance.glsl>
