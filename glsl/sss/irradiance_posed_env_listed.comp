#version 450
// Texture-space irradiance: lights plus a per-vertex rgb irradiance, the texel geometry from this pose's vertex frames, over this frame's reach (pass `sss reach list`). The method: glsl/sss/irradiance.glsl.
#define SSS_POSED 1
#define SSS_ENV 1
#define SSS_LISTED 1
#include <sss/irradiance.glsl>
