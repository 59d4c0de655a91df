#version 450
#extension GL_EXT_samplerless_texture_functions : require
// Cloth under the SG environment, layout "block"; see btf/shade_env.glsl.
#define BTF_MODE 2
#include "shade_env.glsl"
