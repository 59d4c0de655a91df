#version 450
// The compose pass over the rasteriser's covered tiles, dispatched indirectly, after pass
// `compose background` (glsl/compose/background.comp) filled every pixel (the method:
// glsl/compose/shade.glsl).
#define COMPOSE_TILES 1
#include <compose/shade.glsl>
