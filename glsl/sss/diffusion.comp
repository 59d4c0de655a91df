#version 450
// Texture-space subsurface diffusion, importance sampled, one sample set for the three
// channels (one-sample MIS over channels, as pbrt-v3's BSSRDF sampling). The pattern is
// computed on the CPU (cpu::sample_pattern) and read from an image, or compiled in as
// specialization constants (one region, at most 32 samples: glsl/common/sss_diffusion.glsl
// UNIFORM_SAMPLES): radii r_s stratified over the mixture pdf p = mean_c p_c, per-channel
// weights w_c(r_s) = p_c(r_s) / p(r_s), directions on the golden-angle spiral; each texel
// turns the whole pattern by its own hashed angle.
// A sample is an offset r (cos phi, sin phi) in the plane of the receiver's triangle:
// inside the triangle it is read through the triangle's UV map (the circle becomes its
// ellipse: the deformation correction, exact for the current pose; area is accounted for
// because offsets are drawn in surface area, not in UV). Leaving the triangle, it is read
// through the neighbour across the edge it leaves by, unfolded into the triangle's plane
// (seams included: src/kernels/sss/walk.rs); past an open edge it counts with no light; a
// lost sample (non-manifold edge, outside the texture) leaves and the rest renormalise.
// B_c(xo) = R_tot,c * sum w_c E_c / sum w_c (the tail beyond the sampling radius taken at
// the sampled mean), plus the contact sums over other pieces of the mesh within reach
// (src/kernels/sss/contact.rs). The CPU twin is src/kernels/sss/cpu.rs (same pattern, same
// arithmetic). This variant: rgb irradiance from `irr` (see glsl/common/sss_diffusion.glsl).
#include <common/sss_diffusion.glsl>
