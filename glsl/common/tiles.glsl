// The compute rasteriser's 16 x 4 pixel tiles (glsl/raster/tiles.comp lists the covered ones;
// src/kernels/raster/pack.rs TILE): tile t = ty * tiles_x + tx of an image `width`
// pixels wide, tiles_x = ceil(width / 16), covers pixels (tx, ty) * (16, 4) + [0, 16) x [0, 4).
#ifndef VKSHADE_TILES_GLSL
#define VKSHADE_TILES_GLSL
const uvec2 TILE_SIZE = uvec2(16u, 4u);

uint tiles_across(uint width) {
    return (width + TILE_SIZE.x - 1u) / TILE_SIZE.x;
}

// Pixel `local` (in [0, 16) x [0, 4)) of tile t.
uvec2 tile_pixel(uint t, uint width, uvec2 local) {
    uint tiles_x = tiles_across(width);
    return uvec2(t % tiles_x, t / tiles_x) * TILE_SIZE + local;
}

// The tile holding pixel p.
uint tile_of(uvec2 p, uint width) {
    return (p.y / TILE_SIZE.y) * tiles_across(width) + p.x / TILE_SIZE.x;
}
#endif
