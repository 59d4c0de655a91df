#version 450
#extension GL_EXT_samplerless_texture_functions : require
// BTF shading over the rasteriser's tile list (indirect), layout "rows" (one 81-layer array, images side by side with gutters); see common/btf_shade.glsl.
#define BTF_TILES
#define BTF_MODE 1
#include <common/btf_shade.glsl>
