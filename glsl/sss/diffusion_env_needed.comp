#version 450
// glsl/sss/diffusion_env.comp on the row segments a caller needs this frame only (a bitmap:
// glsl/common/sss_diffusion.glsl, SSS_NEEDED); the character frame marks the segments its
// compose pass reads (glsl/compose/need.comp).
#define SSS_ENV 1
#define SSS_NEEDED 1
#include <common/sss_diffusion.glsl>
