#version 450
// glsl/sss/diffusion_env.comp on the row segments a caller needs this frame only, listed
// by pass `sss needed list` (glsl/sss/needed_list.comp) from the caller's bitmap and
// dispatched indirectly over that list (glsl/common/sss_diffusion.glsl, SSS_LISTED); the
// character frame marks the segments its compose pass reads (glsl/compose/need.comp).
#define SSS_ENV 1
#define SSS_LISTED 1
#include <common/sss_diffusion.glsl>
