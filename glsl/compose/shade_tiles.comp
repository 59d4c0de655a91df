#version 450
// The compose pass over the rasteriser's listed tiles, dispatched indirectly, after pass
// `compose background` (glsl/compose/background.comp), which gives every pixel the
// background on frames when it changed (the method: glsl/compose/shade.glsl).
#define COMPOSE_TILES 1
#include <compose/shade.glsl>
