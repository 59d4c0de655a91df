#version 450
#extension GL_EXT_samplerless_texture_functions : require
// BTF shading over the rasteriser's tile list (indirect), texture "block" (rows of overlapping 4 x 4 blocks decoded and filtered here); see common/btf_shade.glsl.
#define BTF_TILES
#define BTF_MODE 2
#include <common/btf_shade.glsl>
