//! BTF (bidirectional texture function) cloth shading: 81 view x 81 light directions of a
//! small texture tile, packed into array textures, interpolated per pixel through parabolic
//! index/weight maps (9 taps). `dirs`: the direction set, projection and maps; `synth`:
//! synthetic BTFs ray-cast from periodic heightfields; `load`: UBO2003-style directories and
//! the repeating-tile finder; `pack`: the texels, maps and G-buffer as the GPU holds them;
//! `gpu`: the kernel.

pub mod block;
pub mod cpu;
pub mod dirs;
pub mod gbuffer;
pub mod gpu;
pub mod load;
pub mod pack;
pub mod synth;
