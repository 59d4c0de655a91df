#version 450
// The compose pass over the rasteriser's listed tiles (or one part of them, `compose
// shade` and `compose shade skin` over the split of glsl/compose/classify.comp), dispatched
// indirectly, after pass
// `compose background` (glsl/compose/background.comp), which gives every pixel the
// background on frames when it changed (the method: glsl/compose/shade.glsl).
#define COMPOSE_TILES 1
#include <compose/shade.glsl>
