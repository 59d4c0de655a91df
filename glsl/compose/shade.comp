#version 450
// The compose pass over every pixel of the frame (the method: glsl/compose/shade.glsl).
#include <compose/shade.glsl>
