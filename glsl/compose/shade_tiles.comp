#version 450
// The compose pass over the rasteriser's listed tiles, dispatched indirectly, before pass
// `compose background` (glsl/compose/background.comp) fills the other tiles that need it
// (the method: glsl/compose/shade.glsl).
#define COMPOSE_TILES 1
#include <compose/shade.glsl>
