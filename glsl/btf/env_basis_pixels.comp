#version 450
#extension GL_EXT_samplerless_texture_functions : require
// `btf env basis` over the pixels pass `btf pixels` lists (indirect); see btf/env_basis.glsl.
#define BTF_PIXELS
#include "env_basis.glsl"
