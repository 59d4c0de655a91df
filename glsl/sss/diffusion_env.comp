#version 450
// Texture-space subsurface diffusion of the irradiance pass's rgb E (the lights plus a
// caller's per-vertex irradiance), gathered from one rgba image whose alpha marks the surface
// (-1 where none). The method and the rest: glsl/sss/diffusion.comp and
// glsl/common/sss_diffusion.glsl.
#define SSS_ENV 1
#include <common/sss_diffusion.glsl>
