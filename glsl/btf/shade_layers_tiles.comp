#version 450
#extension GL_EXT_samplerless_texture_functions : require
// BTF shading over the rasteriser's tile list (indirect), layout "layers" (one image per layer, up to four arrays); see common/btf_shade.glsl.
#define BTF_TILES
#define BTF_MODE 0
#include <common/btf_shade.glsl>
