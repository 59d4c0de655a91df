// The compute rasteriser's 16 x 4 pixel tiles (glsl/raster/tiles.comp lists the covered ones;
// src/kernels/raster/pack.rs TILE): tile (tx, ty) of an image `width` pixels wide covers
// pixels (tx, ty) * (16, 4) + [0, 16) x [0, 4); its flag is word ty * tiles_x + tx,
// tiles_x = ceil(width / 16), and its entry in the tile list tx | ty << 16 (`tile_entry`).
// The list holds coordinates, not the flag's index: a pass over the list finds its pixels
// with a mask and a shift, where dividing by tiles_x, a push-constant value, was a scalar
// division per lane (lavapipe), twice per invocation of every pass over the tiles
// (`bench frame`, fastest of 5 alternated runs each: `raster clear`, `raster resolve`,
// `compose need`, `vertex mark`, `btf pixels` and `compose shade` 4.9 -> 4.3 ms together;
// 4.8 -> 4.6 in a later set of 6 on a loaded host).
#ifndef VKSHADE_TILES_GLSL
#define VKSHADE_TILES_GLSL
const uvec2 TILE_SIZE = uvec2(16u, 4u);

uint tiles_across(uint width) {
    return (width + TILE_SIZE.x - 1u) / TILE_SIZE.x;
}

// The tile list's entry of tile (tx, ty).
uint tile_entry(uint tx, uint ty) {
    return tx | (ty << 16u);
}

// Pixel `local` (in [0, 16) x [0, 4)) of the tile of list entry e.
uvec2 tile_pixel(uint e, uvec2 local) {
    return uvec2(e & 0xffffu, e >> 16u) * TILE_SIZE + local;
}

// The tile holding pixel p.
uint tile_of(uvec2 p, uint width) {
    return (p.y / TILE_SIZE.y) * tiles_across(width) + p.x / TILE_SIZE.x;
}
#endif
