#version 450
#extension GL_EXT_samplerless_texture_functions : require
// `btf env basis` over the rasteriser's tile list; see btf/env_basis.glsl.
#define BTF_TILES
#include "env_basis.glsl"
