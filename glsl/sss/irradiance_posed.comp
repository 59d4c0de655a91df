#version 450
// Texture-space irradiance: Lights only, the texel geometry from this pose's vertex frames. The method: glsl/sss/irradiance.glsl.
#define SSS_POSED 1
#include <sss/irradiance.glsl>
