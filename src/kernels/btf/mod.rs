//! BTF (bidirectional texture function) cloth shading: 81 view x 81 light directions of a
//! small texture tile, packed into array textures, interpolated per pixel through parabolic
//! index/weight maps (9 taps). `dirs`: the direction set, projection and maps; `cloth`: the
//! material model, periodic heightfields with a known BRDF (in [`crate::geom`]: the ground
//! truth ray-casts it too); `synth`: synthetic BTFs, the cloth tabulated at the sampled directions; `load`:
//! UBO2003-style directories and the repeating-tile finder; `pack`: the texels, maps and
//! G-buffer as the GPU holds them; `gpu`: the kernel. The G-buffer the pass shades is a scene
//! input, [`crate::scene::gbuffer`].

pub mod basis;
pub mod block;
pub use crate::geom::cloth;
pub mod cpu;
pub mod dirs;
pub mod env;
pub mod gpu;
pub mod load;
pub mod pack;
pub mod synth;
