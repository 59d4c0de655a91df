#version 450
#extension GL_EXT_samplerless_texture_functions : require
// Cloth under the SG environment, layout "layers"; see btf/shade_env.glsl.
#define BTF_MODE 0
#include "shade_env.glsl"
