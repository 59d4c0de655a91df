#version 450
// Texture-space subsurface diffusion, importance sampled, one sample set for the three
// channels (one-sample MIS over channels, as pbrt-v3's BSSRDF sampling). The radii r_s and
// per-channel weights w_c(r_s) = p_c(r_s) / p(r_s) of the mixture pdf p = mean_c p_c come from
// a uniform buffer computed on the CPU (Profile::mixture_sequence: stratified, the same for
// every texel, so each is a scalar load); a texel only rotates the pattern by its own hashed
// angle, and sample s turns by the golden angle from sample s - 1 (a Fibonacci spiral over the
// increasing radii). B_c(xo) = K_c(R) * sum w_c E_c / sum w_c over the accepted samples.
// A sample is a tangent-plane offset r (cos phi, sin phi), mapped to UV by (J^T J)^-1 J^T (the
// circle becomes the texel's ellipse; area is accounted for because the offsets are drawn in
// surface area, not in UV). It reads the 3D position and E of its nearest texel (one image
// load each). Seams: a sample whose 3D position is
// not at distance ~r (within the tolerance, which exceeds the half-texel rounding) is
// rejected; B renormalises over the accepted ones. The CPU twin is src/kernels/sss/cpu.rs
// (same sequence, same arithmetic).
// rgb irradiance from `irr` (see glsl/common/sss_diffusion.glsl).
#include <common/sss_diffusion.glsl>
