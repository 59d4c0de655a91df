#version 450
// Pass `sss irradiance rays` of glsl/sss/irradiance.comp (Lights only, from the per-texel images (a static mesh or an uploaded pose)). The method: glsl/sss/irradiance.glsl.
#define SSS_RAYS 1
#include <sss/irradiance.glsl>
