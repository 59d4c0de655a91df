//! A compute rasteriser: the screen G-buffer of a posed mesh, built on the GPU every frame
//! from the posed buffers (positions, normals, tangents with handedness) and static
//! per-mesh data (triangles with a part id, UVs). Four passes: `raster clear` (last frame's
//! covered keys), `raster visibility` (one invocation per triangle, near-plane clipping,
//! integer edge functions with the top-left rule, `atomicMin` of 64-bit (depth, triangle)
//! keys in a storage buffer; covered 16 x 4 tiles flagged), `raster tiles` (the list of this
//! frame's and last frame's covered tiles, also the indirect command of the next pass) and
//! `raster resolve` (per pixel of the listed tiles: the kept triangle intersected with the
//! pixel's ray, attributes interpolated into the G-buffer layout of
//! [`crate::scene::gbuffer`], which the BTF pass reads, over the same list). With
//! `gpu::Tiling::Full` the clear and resolve cover every pixel and there is no list.
//! `pack`: the camera and the static data; `gpu`: the kernel; `cpu`: its twin.
//!
//! Decisions: back faces are kept (garments are open: their inside shows at collars and
//! hems) with the normal turned to the camera and the handedness flipped with it; triangles
//! crossing the near plane are clipped (up to two sub-triangles), those wholly behind it
//! culled, both counted; triangles reaching past a guard band of 16384 px from the image
//! origin are culled and counted (the fixed-point products must fit 64 bits); pixels no
//! triangle covers hold an all-zero G-buffer texel (valid flag 0).

pub mod cpu;
pub mod gpu;
pub mod pack;
pub mod vertices;
