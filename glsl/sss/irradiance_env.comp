#version 450
// Texture-space irradiance: Lights plus a per-vertex rgb irradiance, from the per-texel images. The method: glsl/sss/irradiance.glsl.
#define SSS_ENV 1
#include <sss/irradiance.glsl>
