#version 450
#extension GL_EXT_samplerless_texture_functions : require
// BTF shading over the pixels pass `btf pixels` lists (indirect), texture layout "block"; see common/btf_shade.glsl.
#define BTF_PIXELS
#define BTF_MODE 2
#include <common/btf_shade.glsl>
