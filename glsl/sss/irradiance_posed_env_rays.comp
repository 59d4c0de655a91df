#version 450
// Pass `sss irradiance rays` of glsl/sss/irradiance_posed_env.comp (Lights plus a per-vertex rgb irradiance, the texel geometry from this pose's vertex frames). The method: glsl/sss/irradiance.glsl.
#define SSS_POSED 1
#define SSS_ENV 1
#define SSS_RAYS 1
#include <sss/irradiance.glsl>
