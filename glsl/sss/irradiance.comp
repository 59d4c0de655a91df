#version 450
// Texture-space irradiance: Lights only, from the per-texel images (a static mesh or an uploaded pose). The method: glsl/sss/irradiance.glsl.
#include <sss/irradiance.glsl>
