// The atlas's 8-texel row segments (segment s = y * ROW_SEGMENTS + x / 8), shared by the
// segment and block bitmaps of the needed and reach lists.
#ifndef VKSHADE_SSS_SEGMENTS_GLSL
#define VKSHADE_SSS_SEGMENTS_GLSL
// Segments a row, ceil(atlas size / 8): a specialization constant (SssKernel's stages,
// kernels::sss::pack::Room::row_segments), so that dividing by it is a shift or a
// multiply, not a scalar division per lane.
layout(constant_id = 17) const uint ROW_SEGMENTS = 64u;
#endif
