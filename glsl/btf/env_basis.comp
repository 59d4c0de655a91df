#version 450
#extension GL_EXT_samplerless_texture_functions : require
// `btf env basis` over every pixel; see btf/env_basis.glsl.
#include "env_basis.glsl"
