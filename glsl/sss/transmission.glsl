// Whether a pipeline computes the transmission through thin parts (SamplerParams::
// transmission), shared by `sss vertex light` and the irradiance shading passes.
#ifndef VKSHADE_SSS_TRANSMISSION_GLSL
#define VKSHADE_SSS_TRANSMISSION_GLSL
// A specialization constant: SssKernel builds each stage that reads it both ways and records
// the one its params ask for. lavapipe runs the body of an `if` on a push-constant word
// under a lane mask even when no lane takes it, so with transmission off the irradiance
// pass still paid the three vertex loads and the store of every texel's transmission, and
// `sss vertex light` a step of a thickness ray and of each light's ray from the back.
// Compiled out, `bench frame` (4 alternated pairs): `sss irradiance` 2.5 -> 2.1-2.3 ms.
// With it true, the push word `mode` still says whether and how (0 off, 1 dipole, 2 Burley).
layout(constant_id = 18) const bool TRANSMISSION = true;
#endif
