#version 450
// Texture-space subsurface diffusion of the irradiance pass's grey E (white lights), gathered
// from a one-channel image. The method and the rest: glsl/sss/diffusion.comp and
// glsl/common/sss_diffusion.glsl.
#define SSS_GREY 1
#include <common/sss_diffusion.glsl>
