//! Texture-space subsurface diffusion: analytic plane cases, the GPU against the CPU twin
//! of the same sampler, the method against the brute-force ground truth on the BCN_Epileptic
//! head, deformation, bad inputs. Every GPU test runs under validation.

// Channel and texel indices run over several parallel arrays at once.
#![allow(clippy::needless_range_loop)]

mod common;

use glam::{DVec3, Vec3};
use vkshade::geom::bvh::Bvh;
use vkshade::kernels::sss::cpu::{self, Light, SamplerParams};
use vkshade::kernels::sss::{Material, Profile, ProfileKind, Regions, SssKernel, SssOutput};
use vkshade::kernels::{Kernel, run_frames};
use vkshade::reference::sss as truth;
use vkshade::scene::texspace::{COVERED, TexGeometry, plane_mesh};

fn profile(kind: ProfileKind) -> Profile {
    Profile::new(kind, Material::SKIN1, 0.99).unwrap()
}

/// One frame on the GPU with `lights` (or an uploaded irradiance instead).
fn gpu_frame(
    ctx: &vkshade::gpu::Context,
    geo: &TexGeometry,
    p: impl Into<Regions>,
    params: SamplerParams,
    lights: &[Light],
    irradiance: Option<&[[f32; 4]]>,
) -> vkshade::Result<SssOutput> {
    let mut setup = ctx.recorder("sss setup")?;
    let kernel = SssKernel::new(&mut setup, geo, p, params)?;
    setup.submit_and_wait()?;
    match irradiance {
        None => {
            let mut out = None;
            run_frames(ctx, &kernel, [lights], 1, |r| {
                for name in ["sss irradiance", "sss diffusion"] {
                    assert!(r.timings.get(name).is_some(), "{name} not timed");
                }
                out = Some(r.output);
                Ok(())
            })?;
            Ok(out.unwrap())
        }
        Some(e) => {
            let mut rec = ctx.recorder("sss diffusion only")?;
            kernel.upload_irradiance(&mut rec, e)?;
            kernel.record_diffusion(&mut rec)?;
            let rb = kernel.read_back(&mut rec)?;
            rec.submit_and_wait()?;
            kernel.collect(&rb)
        }
    }
}

/// Texels of a plane at least `margin` mm inside its edges.
fn interior(geo: &TexGeometry, w: f32, h: f32, margin: f32) -> Vec<usize> {
    (0..geo.texels())
        .filter(|&i| {
            let p = geo.pos[i];
            p[0].abs() <= 0.5 * w - margin && p[1].abs() <= 0.5 * h - margin
        })
        .collect()
}

#[test]
fn uniformly_lit_plane_gives_e_times_r_tot_also_stretched_2_to_1() {
    // The sampler draws radii up to each channel's truncation radius and scales by the
    // untruncated R_tot (the tail taken at the sampled mean): a uniformly lit plane gives
    // E R_tot exactly.
    for kind in [ProfileKind::Dipole, ProfileKind::Burley] {
        let p = profile(kind);
        let rmax = p.max_radius() as f32;
        // Square (1:1) and stretched (2:1 in UV) planes; E = 2 from a light overhead.
        for (w, h) in [(4.0 * rmax, 4.0 * rmax), (6.0 * rmax, 3.0 * rmax)] {
            let geo = TexGeometry::build(&plane_mesh(w, h, 4).unwrap(), 96, 1.0).unwrap();
            let lights = [Light::Directional {
                toward: Vec3::Z,
                e: 2.0,
            }];
            let params = SamplerParams {
                samples: 16,
                ..Default::default()
            };
            let out = common::with_gpu(|ctx| gpu_frame(ctx, &geo, &p, params, &lights, None));
            let bvh = Bvh::build(&geo.positions, &geo.triangles);
            let cpu_e = cpu::irradiance(&geo, &bvh, &lights, params.shadow_refine);
            let inner = interior(&geo, w, h, rmax * 1.02);
            assert!(inner.len() > 100);
            for &i in &inner {
                for c in 0..3 {
                    assert!((out.irradiance[i][c] - 2.0).abs() < 1e-6);
                    assert_eq!(cpu_e[i][c], 2.0);
                    let want = 2.0 * p.r_tot[c] as f32;
                    assert!(
                        (out.diffuse[i][c] - want).abs() <= 1e-5 * want,
                        "{kind:?} {w}x{h} texel {i} ch {c}: {} vs {want}",
                        out.diffuse[i][c]
                    );
                }
                // Every sample lands on the plane.
                assert_eq!(out.diffuse[i][3], 1.0, "texel {i} lost samples");
            }
        }
    }
}

/// Catches: the sample radii scaled (planted x0.3 in `cpu::sample_pattern`: off by 0.22 of
/// R_tot against a bound of 3e-3), as does
/// `quadratic_irradiance_measures_the_second_moment_on_a_stretched_plane`.
#[test]
fn shadow_edge_follows_the_half_plane_integral() {
    // Half plane x < 0 lit (E = 1), uploaded as the irradiance: the sampler's estimate
    // against the analytic truncated integral (scaled by R_tot / K(R), as the sampler
    // scales), across the edge, on a 2:1 stretched plane.
    let p = profile(ProfileKind::Dipole);
    let rmax = p.max_radius() as f32;
    let (w, h) = (6.0 * rmax, 3.0 * rmax);
    let geo = TexGeometry::build(&plane_mesh(w, h, 4).unwrap(), 128, 1.0).unwrap();
    let e: Vec<[f32; 4]> = geo
        .pos
        .iter()
        .map(|q| {
            if q[0] < 0.0 {
                [1.0, 1.0, 1.0, 1.0]
            } else {
                [0.0, 0.0, 0.0, 1.0]
            }
        })
        .collect();
    let params = SamplerParams {
        samples: 256,
        ..Default::default()
    };
    let out = common::with_gpu(|ctx| gpu_frame(ctx, &geo, &p, params, &[], Some(&e)));
    let cpu = cpu::diffusion(&geo, &Regions::from(&p), &e, &params);
    let texel = w / 128.0;
    let inner = interior(&geo, w, h, rmax * 1.02);
    // Mean over texels at the same x (one column of texels) against the 1D integral.
    let mut worst = 0f64;
    let mut columns = std::collections::BTreeMap::<i64, (f64, [f64; 3], usize)>::new();
    for &i in &inner {
        let x = geo.pos[i][0] as f64;
        let col = columns
            .entry((x / texel as f64).floor() as i64)
            .or_insert((x, [0.0; 3], 0));
        for c in 0..3 {
            col.1[c] += out.diffuse[i][c] as f64;
            // GPU and CPU run the same sampler: agreement to float rounding.
            assert!((out.diffuse[i][c] - cpu[i][c]).abs() <= 1e-5 * p.r_tot[c] as f32 + 1e-7);
        }
        col.2 += 1;
    }
    for (_, (x, sum, n)) in columns {
        for c in 0..3 {
            // The sampler reads E at the nearest texel centre; the centres lie at +-texel/2
            // about x = 0, so the E it sees is the step itself.
            let want = truth::shadow_edge(&p, c, x) * p.r_tot[c] / p.k[c];
            let got = sum[c] / n as f64;
            worst = worst.max((got - want).abs() / p.r_tot[c]);
        }
    }
    eprintln!("shadow edge: worst {worst:.5} of R_tot");
    // Measured: 2.45e-3 of R_tot with nearest-texel lookups (256 samples per texel shared by
    // the channels, averaged over a column).
    assert!(worst < 3e-3, "shadow edge off by {worst} of R_tot");
}

fn head(size: u32) -> TexGeometry {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("data/bcn_epileptic.glb");
    let mesh = vkshade::app::sss::load_mesh(&path, Some("Head")).unwrap();
    TexGeometry::build(&mesh, size, 1000.0).unwrap()
}

/// The GPU's diffusion against the brute force from its own irradiance: every 3rd covered
/// texel as a receiver, every covered texel as a source.
fn against_brute_force(geo: &TexGeometry, out: &SssOutput, p: &Profile) -> truth::ChannelError {
    let covered: Vec<usize> = (0..geo.texels())
        .filter(|&i| geo.pos[i][3] == COVERED)
        .step_by(3)
        .collect();
    let receivers: Vec<DVec3> = covered
        .iter()
        .map(|&i| Vec3::from_slice(&geo.pos[i][..3]).as_dvec3())
        .collect();
    let t = truth::brute_force(
        &truth::Sources::from_texels(geo, &out.irradiance),
        &receivers,
        p,
    );
    let est: Vec<[f64; 3]> = covered
        .iter()
        .map(|&i| [0, 1, 2].map(|c| out.diffuse[i][c] as f64))
        .collect();
    let w: Vec<f64> = covered.iter().map(|&i| geo.nrm[i][3] as f64).collect();
    truth::ChannelError::of(&est, &t, &w)
}

#[test]
fn head_gpu_matches_the_cpu_twin_and_the_brute_force() {
    let geo = head(256);
    // The mirrored halves of the face share UVs: repaired into two layers.
    assert!(geo.report.overlapping_texels > 0 && geo.report.layers == 2);
    let p = Profile::new(ProfileKind::Dipole, Material::SKIN1, 0.995).unwrap();
    let lights = [
        Light::Directional {
            toward: Vec3::new(0.3, 0.4, 1.0).normalize(),
            e: 1.0,
        },
        Light::Point {
            pos: Vec3::new(-150.0, 700.0, 100.0),
            i: 2.0e4,
        },
    ];
    let params = SamplerParams {
        samples: 32,
        ..Default::default()
    };
    let out = common::with_gpu(|ctx| gpu_frame(ctx, &geo, &p, params, &lights, None));
    // Irradiance: the same rays through the same BVH; a texel may flip where a shadow ray
    // grazes an edge (f32 rounding differs).
    let e = cpu::irradiance(
        &geo,
        &Bvh::build(&geo.positions, &geo.triangles),
        &lights,
        params.shadow_refine,
    );
    let valid: Vec<usize> = (0..geo.texels()).filter(|&i| geo.pos[i][3] > 0.0).collect();
    let flipped = valid
        .iter()
        .filter(|&&i| (out.irradiance[i][0] - e[i][0]).abs() > 1e-4 * e[i][0].max(1e-3))
        .count();
    assert!(
        flipped * 1000 <= valid.len(),
        "{flipped} texels' irradiance differ"
    );
    assert!(
        valid.iter().any(|&i| e[i][0] == 0.0),
        "no self-shadowing at all"
    );
    // Shadows from the vertices, refined per texel where a triangle's corners disagree,
    // against a shadow ray from every texel: only shadows that touch no corner of their
    // triangle differ.
    let rays =
        cpu::irradiance_per_texel_rays(&geo, &Bvh::build(&geo.positions, &geo.triangles), &lights);
    let (mut d2, mut t2) = (0f64, 0f64);
    for &i in &valid {
        d2 += ((e[i][0] - rays[i][0]) as f64).powi(2);
        t2 += (rays[i][0] as f64).powi(2);
    }
    let shadow_rmse = (d2 / t2).sqrt();
    // Measured 0.020 (256^2, these two lights; gutter texels interpolate, they are not
    // surface).
    eprintln!("refined vertex shadows vs a ray per texel: E rel RMSE {shadow_rmse:.4}");
    assert!(shadow_rmse < 0.03, "E rel RMSE {shadow_rmse}");
    // Transmission: the same thickness rays per vertex; a vertex may differ where its ray
    // grazes an edge (f32 rounding differs), and its value spreads over the texels of its
    // triangles (at 256^2 one vertex covers ~60 texels): at most 0.5% of the texels.
    let tr = cpu::transmission(
        &geo,
        &Bvh::build(&geo.positions, &geo.triangles),
        &lights,
        &Regions::from(&p),
    );
    let tmax = valid.iter().map(|&i| tr[i][0]).fold(0f32, f32::max);
    assert!(tmax > 0.0, "nothing transmits through the head");
    let differ = valid
        .iter()
        .filter(|&&i| {
            (0..4).any(|c| (out.transmission[i][c] - tr[i][c]).abs() > 1e-4 * tmax.max(tr[i][3]))
        })
        .count();
    eprintln!("transmission: {differ} of {} texels differ", valid.len());
    assert!(
        differ * 200 <= valid.len(),
        "{differ} texels' transmission differ"
    );
    // Diffusion: the same sample pattern from the GPU's irradiance. Measured relative RMSE 0
    // (the same arithmetic); a sample may flip at a triangle edge or texel boundary where the
    // driver's cos / sin or a fused multiply-add rounds differently from the CPU.
    let b = cpu::diffusion(&geo, &Regions::from(&p), &out.irradiance, &params);
    for c in 0..3 {
        let (mut d2, mut t2) = (0f64, 0f64);
        for &i in &valid {
            d2 += ((out.diffuse[i][c] - b[i][c]) as f64).powi(2);
            t2 += (b[i][c] as f64).powi(2);
        }
        let rel = (d2 / t2).sqrt();
        assert!(
            rel < 1e-5,
            "channel {c}: GPU vs CPU twin relative RMSE {rel}"
        );
    }
    let err = against_brute_force(&geo, &out, &p);
    eprintln!("head 256^2 x 32 vs brute force: {err:?}");
    // Measured at 256^2 x 32 shared samples (2.5 mm texels, these two lights): relative RMSE
    // 0.056 / 0.040 / 0.083, energy ratio 0.987 / 1.003 / 1.056. Blue is coarse against its
    // 3.5 mm radius: most of its light comes from within a texel or two of the receiver,
    // which the truth integrates with 4 x 4 points per texel. The 512^2 test below holds
    // the target. Bounds with margin:
    let bound = [0.07, 0.05, 0.10];
    let energy = [0.03, 0.03, 0.07];
    for c in 0..3 {
        assert!(err.rel_rmse[c] < bound[c], "channel {c}: {err:?}");
        assert!(
            (err.energy_ratio[c] - 1.0).abs() < energy[c],
            "channel {c}: {err:?}"
        );
    }
}

#[test]
fn head_512_meets_the_accuracy_target() {
    // The target on the real head: 512^2, 64 samples per texel, relative RMSE <= 5%
    // per channel and energy within 2% of the brute force (every 3rd covered texel as a
    // receiver, every covered texel as a source), under the default light.
    let geo = head(512);
    let p = Profile::new(ProfileKind::Dipole, Material::SKIN1, 0.995).unwrap();
    let lights = [Light::Directional {
        toward: Vec3::new(0.3, 0.4, 1.0).normalize(),
        e: 1.0,
    }];
    let params = SamplerParams {
        samples: 64,
        ..Default::default()
    };
    let out = common::with_gpu(|ctx| gpu_frame(ctx, &geo, &p, params, &lights, None));
    let err = against_brute_force(&geo, &out, &p);
    eprintln!("head 512^2 x 64 vs brute force: {err:?}");
    for c in 0..3 {
        assert!(err.rel_rmse[c] <= 0.05, "channel {c}: {err:?}");
        assert!(
            (err.energy_ratio[c] - 1.0).abs() <= 0.02,
            "channel {c}: {err:?}"
        );
    }
}

#[test]
fn bad_inputs_are_refused_with_clear_errors() {
    // Lights.
    for bad in [
        "dir:0,0,0",
        "dir:1,x,0",
        "point:1,2,3",
        "spot:1,2,3:1",
        "dir:0,1,0:-1",
        "dir",
    ] {
        let e = Light::parse(bad, 1.0).unwrap_err().to_string();
        assert!(e.contains(bad), "{e}");
    }
    // A mesh without UVs (OBJ without vt): the error names the file.
    let obj = common::temp_file("sss", "no_uv.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n");
    let mesh = vkshade::app::sss::load_mesh(&obj, None).unwrap();
    let e = common::error_naming(&obj, TexGeometry::build(&mesh, 64, 1.0));
    assert!(e.contains("no texture coordinates"), "{e}");
    // An unknown glTF part names the file and lists the meshes.
    let glb = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("data/bcn_epileptic.glb");
    let e = common::error_naming(&glb, vkshade::app::sss::load_mesh(&glb, Some("Tail")));
    assert!(e.contains("Tail") && e.contains("Head"), "{e}");
    // Sizes, samples, frames of the wrong shape.
    let geo = TexGeometry::build(&plane_mesh(10.0, 10.0, 2).unwrap(), 32, 1.0).unwrap();
    let e = TexGeometry::build(&plane_mesh(10.0, 10.0, 2).unwrap(), 4, 1.0).unwrap_err();
    assert!(e.to_string().contains("texture size 4"), "{e}");
    let p = profile(ProfileKind::Burley);
    common::with_gpu(|ctx| {
        let mut rec = ctx.recorder("bad sss")?;
        let zero = SamplerParams {
            samples: 0,
            ..Default::default()
        };
        let e = SssKernel::new(&mut rec, &geo, &p, zero).err().unwrap();
        assert!(e.to_string().contains("samples"), "{e}");
        // A hand-built geometry whose texel names a triangle the mesh does not have (the
        // shaders would index past the triangle records), or a triangle a missing vertex.
        let mut broken = geo.clone();
        let on = (0..broken.texels())
            .find(|&i| broken.pos[i][3] != 0.0)
            .unwrap();
        broken.texel_tri[on][0] = 99;
        let e = SssKernel::new(&mut rec, &broken, &p, SamplerParams::default())
            .err()
            .unwrap();
        assert!(e.to_string().contains("triangle 99"), "{e}");
        let mut broken = geo.clone();
        broken.triangles[1][2] = 1000;
        let e = SssKernel::new(&mut rec, &broken, &p, SamplerParams::default())
            .err()
            .unwrap();
        assert!(e.to_string().contains("triangle 1 names a vertex"), "{e}");
        // Fewer UV corner triples than triangles: the walk would read past its records.
        let mut broken = geo.clone();
        broken.corner_uvs.pop();
        let e = SssKernel::new(&mut rec, &broken, &p, SamplerParams::default())
            .err()
            .unwrap();
        assert!(e.to_string().contains("UV corner triples"), "{e}");
        let kernel = SssKernel::new(&mut rec, &geo, &p, SamplerParams::default())?;
        let e = kernel
            .upload_irradiance(&mut rec, &[[0.0; 4]; 7])
            .unwrap_err();
        assert!(e.to_string().contains("7 irradiance texels"), "{e}");
        let mut nan = vec![[1.0f32; 4]; geo.texels()];
        nan[5][1] = f32::NAN;
        let e = kernel.upload_irradiance(&mut rec, &nan).unwrap_err();
        assert!(e.to_string().contains("texel 5"), "{e}");
        let many = vec![
            Light::Directional {
                toward: Vec3::Z,
                e: 1.0
            };
            cpu::MAX_LIGHTS + 1
        ];
        let e = kernel.record(&mut rec, &many).unwrap_err();
        assert!(e.to_string().contains("lights"), "{e}");
        let n = kernel.passes().len();
        let e = kernel.record_pass(&mut rec, n, &[]).unwrap_err();
        assert!(e.to_string().contains(&format!("{n} passes")), "{e}");
        rec.submit_and_wait()?;
        Ok(())
    });
}

/// The triangles of `geo` whose centroid lies at x >= 0 in region 1, the others in 0.
fn halves(geo: &TexGeometry) -> Vec<u8> {
    geo.triangles
        .iter()
        .map(|t| {
            let x: f32 = t.iter().map(|&v| geo.positions[v as usize].x).sum();
            (x >= 0.0) as u8
        })
        .collect()
}

/// Multi-region skin (`kernels::sss::regions`): a plane whose left half is skin 1 and right
/// half skin 2 (Jensen's measured skins; skin 2's dipole R_tot is 1.4x, 1.9x and 2.6x skin 1's
/// in r, g, b). Each texel
/// diffuses with its own region's profile (the exit point's): under uniform light every
/// interior texel is E R_tot of its own region, right up to the border between them (the
/// profile is the receiver's, and E is the same wherever the samples land), so a texel that
/// took the other region's profile is off by 30-160% against a 1e-5 bound. Then the GPU
/// against its CPU twin on an irradiance with an edge near the border (1e-5 of the
/// largest value). Catches: the diffusion shader ignoring the region (every texel on region
/// 0's rows of the pattern image; checked by planting `row = 0`), the region's R_tot or
/// totals read from another row, and the walk records losing the region.
#[test]
fn two_skin_regions_each_diffuse_with_their_own_profile() {
    for kind in [ProfileKind::Dipole, ProfileKind::Burley] {
        let skin1 = profile(kind);
        let skin2 = Profile::new(kind, Material::SKIN2, 0.99).unwrap();
        let rmax = skin1.max_radius().max(skin2.max_radius()) as f32;
        let (w, h) = (6.0 * rmax, 3.0 * rmax);
        let geo = TexGeometry::build(&plane_mesh(w, h, 8).unwrap(), 96, 1.0).unwrap();
        let regions = Regions::new(vec![skin1.clone(), skin2.clone()], halves(&geo)).unwrap();
        let region_of = |i: usize| regions.of_triangle(geo.texel_tri[i][0] as usize);
        let params = SamplerParams {
            samples: 16,
            ..Default::default()
        };
        let lights = [Light::Directional {
            toward: Vec3::Z,
            e: 2.0,
        }];
        // A step in the irradiance 0.3 rmax right of the border (an uploaded E).
        let step: Vec<[f32; 4]> = geo
            .pos
            .iter()
            .map(|p| {
                let e = if p[0] > 0.3 * rmax { 2.0 } else { 0.5 };
                [e, e, e, 1.0]
            })
            .collect();
        let (lit, stepped) = common::with_gpu(|ctx| {
            let mut setup = ctx.recorder("sss regions setup")?;
            let kernel = SssKernel::new(&mut setup, &geo, &regions, params)?;
            setup.submit_and_wait()?;
            assert_eq!(kernel.regions().len(), 2);
            let mut lit = None;
            run_frames(ctx, &kernel, [&lights[..]], 1, |r| {
                lit = Some(r.output);
                Ok(())
            })?;
            let mut rec = ctx.recorder("sss regions step")?;
            kernel.upload_irradiance(&mut rec, &step)?;
            kernel.record_diffusion(&mut rec)?;
            let rb = kernel.read_back(&mut rec)?;
            rec.submit_and_wait()?;
            Ok((lit.unwrap(), kernel.collect(&rb)?))
        });
        let inner = interior(&geo, w, h, rmax * 1.02);
        let per_region = [0, 1].map(|r| inner.iter().filter(|&&i| region_of(i) == r).count());
        assert!(per_region.iter().all(|&n| n > 100), "{per_region:?}");
        for &i in &inner {
            let p = [&skin1, &skin2][region_of(i)];
            for c in 0..3 {
                let want = 2.0 * p.r_tot[c] as f32;
                assert!(
                    (lit.diffuse[i][c] - want).abs() <= 1e-5 * want,
                    "{kind:?} texel {i} (region {}) ch {c}: {} vs {want}",
                    region_of(i),
                    lit.diffuse[i][c]
                );
            }
        }
        // The two profiles are far enough apart for the bound above to tell them apart.
        for c in 0..3 {
            let (a, b) = (skin1.r_tot[c], skin2.r_tot[c]);
            assert!((a - b).abs() > 0.03 * a, "ch {c}: R_tot {a} vs {b}");
        }
        let cpu_b = cpu::diffusion(&geo, &regions, &step, &params);
        let top = cpu_b
            .iter()
            .map(|b| b[0].max(b[1]).max(b[2]))
            .fold(0f32, f32::max);
        let worst = (0..geo.texels())
            .map(|i| {
                (0..3)
                    .map(|c| (stepped.diffuse[i][c] - cpu_b[i][c]).abs())
                    .fold(0f32, f32::max)
            })
            .fold(0f32, f32::max);
        eprintln!("{kind:?}: two regions, GPU vs CPU twin worst {worst:e} (of {top})");
        assert!(
            worst <= 1e-5 * top,
            "{kind:?}: GPU vs CPU twin {worst} of {top}"
        );
    }
}

/// Two parallel planes `t` = 3 mm apart, facing away from each other (front +z at z = 0,
/// back -z at z = -3), their UVs side by side, at 64^2 texels.
fn slab() -> (TexGeometry, f32) {
    use vkshade::scene::mesh::{Mesh, MeshData};
    let (w, t) = (60.0f32, 3.0f32);
    let mut d = MeshData {
        name: "slab".into(),
        ..Default::default()
    };
    let mut uvs = Vec::new();
    let mut normals = Vec::new();
    // Grids of cells (transmission is computed per vertex): the back plane is larger and
    // offset, with another cell count, so no thickness ray from a front vertex grazes a back
    // edge or vertex.
    for (z, nz, u0, size, g, shift) in [
        (0.0, 1.0, 0.0, w, 6u32, 0.0),
        (-t, -1.0, 0.5, w + 20.0, 5, 3.7),
    ] {
        let b = d.positions.len() as u32;
        for j in 0..=g {
            for k in 0..=g {
                let (x, y) = (k as f32 / g as f32, j as f32 / g as f32);
                d.positions
                    .push([(x - 0.5) * size + shift, (y - 0.5) * size + 0.8 * shift, z]);
                uvs.push([u0 + 0.5 * x, y]);
                normals.push([0.0, 0.0, nz]);
            }
        }
        for j in 0..g {
            for k in 0..g {
                let q = b + j * (g + 1) + k;
                let (q1, q2, q3) = (q + 1, q + g + 2, q + g + 1);
                if nz > 0.0 {
                    d.triangles.extend([[q, q1, q2], [q, q2, q3]]);
                } else {
                    d.triangles.extend([[q, q2, q1], [q, q3, q2]]);
                }
            }
        }
    }
    d.uvs = Some(uvs);
    d.normals = Some(normals);
    let mesh = Mesh::from_data(d, std::path::Path::new("<slab>")).unwrap();
    let geo = TexGeometry::build(&mesh, 64, 1.0).unwrap();
    (geo, t)
}

#[test]
fn back_lit_thin_slab_transmits_red() {
    // Two parallel planes 3 mm apart, facing away from each other (front +z at z = 0, back -z at
    // z = -3), their UVs side by side; lit from behind (-z). The front gets no irradiance,
    // only the transmission E (R_tot - F(3 mm)), red far above blue.
    let (geo, t) = slab();
    let p = profile(ProfileKind::Dipole);
    let lights = [Light::Directional {
        toward: -Vec3::Z,
        e: 1.0,
    }];
    let params = SamplerParams {
        samples: 4,
        ..Default::default()
    };
    let out = common::with_gpu(|ctx| gpu_frame(ctx, &geo, &p, params, &lights, None));
    let bvh = Bvh::build(&geo.positions, &geo.triangles);
    let cpu_t = cpu::transmission(&geo, &bvh, &lights, &Regions::from(&p));
    let want = [0, 1, 2].map(|c| p.tail_f32(c, t));
    let mut front = 0;
    for i in 0..geo.texels() {
        if geo.pos[i][3] != COVERED || geo.pos[i][2] != 0.0 {
            continue;
        }
        front += 1;
        assert_eq!(out.irradiance[i][0], 0.0);
        assert!(
            (out.transmission[i][3] - t).abs() < 1e-4,
            "thickness {}",
            out.transmission[i][3]
        );
        for c in 0..3 {
            assert!((out.transmission[i][c] - want[c]).abs() <= 1e-4 * want[c]);
            assert!((cpu_t[i][c] - out.transmission[i][c]).abs() <= 1e-5 * want[c]);
        }
        // Thin skin lit from behind glows red.
        assert!(out.transmission[i][0] > 5.0 * out.transmission[i][2]);
    }
    assert!(front > 1000, "{front} front texels");
    // Two regions (multi-region skin): the right half skin 2. A vertex takes the lowest
    // region around it, so a front texel whose triangle's corners are all in region r
    // transmits region r's tail; those across the middle column blend both. Catches the
    // transmission pass reading one region's tail for every vertex (skin 2's dipole tail
    // beyond 3 mm is about 1.4x, 2.2x and 10x skin 1's in r, g, b; the bound 1e-4).
    let skin2 = Profile::new(ProfileKind::Dipole, Material::SKIN2, 0.99).unwrap();
    let regions = Regions::new(vec![p.clone(), skin2.clone()], halves(&geo)).unwrap();
    let vreg = regions.of_vertices(&geo.triangles, geo.positions.len());
    let out = common::with_gpu(|ctx| gpu_frame(ctx, &geo, &regions, params, &lights, None));
    let cpu_t = cpu::transmission(&geo, &bvh, &lights, &regions);
    let tails = [&p, &skin2].map(|q| [0, 1, 2].map(|c| q.tail_f32(c, t)));
    for c in 0..3 {
        assert!(tails[1][c] > 1.05 * tails[0][c], "ch {c}: {tails:?}");
    }
    let mut seen = [0usize; 2];
    for i in 0..geo.texels() {
        if geo.pos[i][3] != COVERED || geo.pos[i][2] != 0.0 {
            continue;
        }
        let corners = geo.triangles[geo.texel_tri[i][0] as usize].map(|v| vreg[v as usize]);
        for c in 0..3 {
            let scale = tails[1][c];
            assert!(
                (cpu_t[i][c] - out.transmission[i][c]).abs() <= 1e-5 * scale,
                "texel {i} ch {c}: GPU {} vs CPU twin {}",
                out.transmission[i][c],
                cpu_t[i][c]
            );
        }
        for r in 0..2 {
            if corners.iter().all(|&x| x as usize == r) {
                seen[r] += 1;
                for c in 0..3 {
                    let want = tails[r][c];
                    assert!(
                        (out.transmission[i][c] - want).abs() <= 1e-4 * want,
                        "texel {i} region {r} ch {c}: {} vs {want}",
                        out.transmission[i][c]
                    );
                }
            }
        }
    }
    assert!(seen.iter().all(|&n| n > 200), "texels per region {seen:?}");
}

/// Catches: a transmission switch that records the build of `sss vertex light` or `sss
/// irradiance` with the transmission compiled out while transmission is on (each is built
/// with its transmission code compiled in and compiled out, glsl/sss/transmission.glsl, and
/// the params pick one), or that leaves the old transmission behind. One kernel on the
/// back-lit slab: with transmission the front transmits; switched off (`set_params`) the
/// transmission image holds zeros and the rest is unchanged; switched on again, the first
/// frame's output bit for bit. (The build with transmission compiled in, recorded while it is
/// off, gives the same images, its push word saying off: only slower.)
#[test]
fn switching_transmission_off_and_on_records_the_matching_passes() {
    let (geo, _) = slab();
    let p = profile(ProfileKind::Dipole);
    let lights = [Light::Directional {
        toward: -Vec3::Z,
        e: 1.0,
    }];
    let on = SamplerParams {
        samples: 4,
        transmission: true,
        ..Default::default()
    };
    let off = SamplerParams {
        transmission: false,
        ..on
    };
    let [with, without, again] = common::with_gpu(|ctx| {
        let mut setup = ctx.recorder("sss setup")?;
        let mut kernel = SssKernel::new(&mut setup, &geo, &p, on)?;
        setup.submit_and_wait()?;
        let mut outs = Vec::new();
        for params in [on, off, on] {
            let mut rec = ctx.recorder("sss params")?;
            kernel.set_params(&mut rec, params)?;
            rec.submit_and_wait()?;
            run_frames(ctx, &kernel, [&lights[..]], 1, |r| {
                outs.push(r.output);
                Ok(())
            })?;
        }
        Ok(<[SssOutput; 3]>::try_from(outs).unwrap())
    });
    let front: Vec<usize> = (0..geo.texels())
        .filter(|&i| geo.pos[i][3] == COVERED && geo.pos[i][2] == 0.0)
        .collect();
    assert!(front.len() > 1000, "{} front texels", front.len());
    assert!(
        front.iter().all(|&i| with.transmission[i][0] > 0.0),
        "the front does not transmit with transmission on"
    );
    assert!(
        without.transmission.iter().all(|t| *t == [0.0; 4]),
        "transmission left in the image with transmission off"
    );
    assert_eq!(with.irradiance, without.irradiance);
    assert_eq!(with.diffuse, without.diffuse);
    assert_eq!(with.transmission, again.transmission);
    assert_eq!(with.irradiance, again.irradiance);
}

/// Catches: a diffusion pipeline left with the sample pattern of the kernel's first params.
/// With one region and at most `pack::MAX_UNIFORM_SAMPLES` samples the diffusion holds the
/// pattern (and its sample count) as specialization constants, so `set_params` must build its
/// pipelines again when the count changes: the grey one (after the irradiance pass), the rgb
/// one (an uploaded irradiance) and that of a per-vertex irradiance. One kernel per pipeline
/// on a plane lit off centre by a point light, its sample count changed 8 -> 32 (constants)
/// -> 48 (the pattern image) -> 8: each frame's diffusion equals the CPU twin at that count,
/// and each differs from the count before it.
#[test]
fn changing_the_sample_count_rebuilds_the_diffusion_with_its_pattern() {
    let p = profile(ProfileKind::Dipole);
    let rmax = p.max_radius() as f32;
    let geo = TexGeometry::build(&plane_mesh(4.0 * rmax, 4.0 * rmax, 4).unwrap(), 64, 1.0).unwrap();
    let lights = [Light::Point {
        pos: Vec3::new(0.5 * rmax, 0.2 * rmax, 0.5 * rmax),
        i: 1.0e3,
    }];
    let uploaded = cpu::irradiance(
        &geo,
        &Bvh::build(&geo.positions, &geo.triangles),
        &lights,
        true,
    );
    let ve = vertex_irradiance(&geo);
    let counts = [8, 32, 48, 8];
    let with = |samples| SamplerParams {
        samples,
        ..Default::default()
    };
    let paths = ["grey", "rgb", "per-vertex"];
    let outs = common::with_gpu(|ctx| {
        let mut outs = Vec::new();
        for path in paths {
            let mut setup = ctx.recorder("sss setup")?;
            let mut kernel = SssKernel::new(&mut setup, &geo, &p, with(counts[0]))?;
            if path == "per-vertex" {
                let buffer = vertex_buffer(&mut setup, &ve)?;
                kernel.set_vertex_irradiance(&mut setup, Some(&buffer))?;
            }
            setup.submit_and_wait()?;
            for samples in counts {
                let mut rec = ctx.recorder("sss params")?;
                kernel.set_params(&mut rec, with(samples))?;
                rec.submit_and_wait()?;
                if path == "rgb" {
                    let mut rec = ctx.recorder("sss uploaded diffusion")?;
                    kernel.upload_irradiance(&mut rec, &uploaded)?;
                    kernel.record_diffusion(&mut rec)?;
                    let rb = kernel.read_back(&mut rec)?;
                    rec.submit_and_wait()?;
                    outs.push(kernel.collect(&rb)?);
                } else {
                    run_frames(ctx, &kernel, [&lights[..]], 1, |r| {
                        outs.push(r.output);
                        Ok(())
                    })?;
                }
            }
        }
        Ok(outs)
    });
    let covered: Vec<usize> = (0..geo.texels())
        .filter(|&i| geo.pos[i][3] == COVERED)
        .collect();
    assert!(covered.len() > 3000);
    let regions = Regions::from(&p);
    for (path, runs) in paths.iter().zip(outs.chunks(counts.len())) {
        let mut last: Option<&[[f32; 4]]> = None;
        for (out, samples) in runs.iter().zip(counts) {
            let twin = cpu::diffusion(&geo, &regions, &out.irradiance, &with(samples));
            let (mut worst, mut moved) = (0f32, 0f32);
            for &i in &covered {
                for c in 0..3 {
                    let b = out.diffuse[i][c];
                    let scale = b.max(1e-3 * p.r_tot[c] as f32);
                    worst = worst.max((b - twin[i][c]).abs() / scale);
                    if let Some(prev) = last {
                        moved = moved.max((b - prev[i][c]).abs() / scale);
                    }
                }
            }
            eprintln!("{path}, {samples} samples: GPU vs twin {worst:.2e}");
            // The same pattern and arithmetic: f32 rounding only (measured 0 at every count).
            assert!(
                worst <= 1e-5,
                "{path}, {samples} samples: GPU vs twin off by {worst}"
            );
            // Another count is another pattern: a frame that kept the last one would match it.
            if last.is_some() {
                eprintln!("{path}, {samples} samples: {moved:.3} from the count before");
                assert!(
                    moved > 1e-3,
                    "{path}, {samples} samples: the same diffusion as before"
                );
            }
            last = Some(&out.diffuse);
        }
    }
}

/// Catches: `SssKernel::update_geometry` made a no-op (or uploading only some of the
/// geometry). The kernel is built for a square plane, then the next frame's geometry (the
/// same triangles and UVs, stretched 2:1 in 3D) is uploaded and lit by a point light off
/// centre: the irradiance follows the stretched positions (against the CPU twin and the
/// closed form I cos / d^2), and the diffusion of it follows the stretched triangles (the
/// CPU twin on the stretched geometry). The square geometry's result is far from both, so
/// a frame still on the old geometry fails. A uniformly lit plane (the test's old light) is
/// E R_tot on either geometry and could not tell them apart.
#[test]
fn a_frame_that_stretches_the_mesh_follows_the_new_geometry() {
    let p = profile(ProfileKind::Dipole);
    let rmax = p.max_radius() as f32;
    let square =
        TexGeometry::build(&plane_mesh(4.0 * rmax, 4.0 * rmax, 4).unwrap(), 64, 1.0).unwrap();
    let (w, h) = (6.0 * rmax, 3.0 * rmax);
    let stretched = TexGeometry::build(&plane_mesh(w, h, 4).unwrap(), 64, 1.0).unwrap();
    let light = Vec3::new(0.4 * w, 0.1 * h, 0.5 * rmax);
    let lights = [Light::Point {
        pos: light,
        i: 1.0e3,
    }];
    let params = SamplerParams {
        samples: 8,
        ..Default::default()
    };
    let out = common::with_gpu(|ctx| {
        let mut setup = ctx.recorder("sss setup")?;
        let kernel = SssKernel::new(&mut setup, &square, &p, params)?;
        setup.submit_and_wait()?;
        let mut rec = ctx.recorder("sss stretched frame")?;
        kernel.update_geometry(&mut rec, &stretched)?;
        kernel.record(&mut rec, &lights[..])?;
        let rb = kernel.read_back(&mut rec)?;
        rec.submit_and_wait()?;
        // A geometry of another size is refused.
        let mut rec = ctx.recorder("sss wrong geometry")?;
        let other = TexGeometry::build(&plane_mesh(w, h, 4).unwrap(), 32, 1.0)?;
        let e = kernel.update_geometry(&mut rec, &other).unwrap_err();
        assert!(e.to_string().contains("does not match"), "{e}");
        rec.submit_and_wait()?;
        kernel.collect(&rb)
    });
    let bvh = Bvh::build(&stretched.positions, &stretched.triangles);
    let cpu_e = cpu::irradiance(&stretched, &bvh, &lights, params.shadow_refine);
    let cpu_b = cpu::diffusion(&stretched, &Regions::from(&p), &out.irradiance, &params);
    let old_e = cpu::irradiance(
        &square,
        &Bvh::build(&square.positions, &square.triangles),
        &lights,
        params.shadow_refine,
    );
    let old_b = cpu::diffusion(&square, &Regions::from(&p), &old_e, &params);
    let covered: Vec<usize> = (0..stretched.texels())
        .filter(|&i| stretched.pos[i][3] == COVERED)
        .collect();
    assert!(covered.len() > 3000);
    let (mut e_off_old, mut b_off_old, mut b_max) = (0f32, 0f32, 0f32);
    for &i in &covered {
        let q = Vec3::from_slice(&stretched.pos[i][..3]);
        let d = light - q;
        // Closed form on the plane z = 0 (normal +z, no shadows): I cos / d^2 = I d_z / d^3.
        let exact = 1.0e3 * d.z / d.length().powi(3);
        for c in 0..3 {
            let e = out.irradiance[i][c];
            // Interpolated per-vertex visibility, the same lights: f32 rounding only.
            assert!(
                (e - cpu_e[i][c]).abs() <= 1e-5 * e,
                "{i} {c}: {e} vs {}",
                cpu_e[i][c]
            );
            assert!((e - exact).abs() <= 1e-4 * exact, "{i} {c}: {e} vs {exact}");
            let b = out.diffuse[i][c];
            assert!(
                (b - cpu_b[i][c]).abs() <= 1e-5 * b.max(1e-3 * p.r_tot[c] as f32),
                "{i} {c}: {b} vs {}",
                cpu_b[i][c]
            );
            e_off_old = e_off_old.max((e - old_e[i][c]).abs() / exact);
            b_off_old = b_off_old.max((b - old_b[i][c]).abs());
            b_max = b_max.max(b);
        }
    }
    // The old geometry is far from the new one's answer, so the comparisons above have power.
    eprintln!(
        "old geometry: E off by {e_off_old:.2} of E, B by {:.2} of max B",
        b_off_old / b_max
    );
    assert!(e_off_old > 0.5 && b_off_old > 0.1 * b_max);
}

/// int_0^R 2 pi r Rd_c(r) r^2 dr / K_c(R): the truncated profile's normalised second moment
/// (mm^2), by the midpoint rule on 200,000 radii (independent of the sampler's tables).
fn second_moment(p: &Profile, c: usize) -> f64 {
    let (n, r_max) = (200_000, p.radius[c]);
    let h = r_max / n as f64;
    let mut m = 0.0;
    for i in 0..n {
        let r = (i as f64 + 0.5) * h;
        m += 2.0 * std::f64::consts::PI * r * p.rd(c, r) * r * r * h;
    }
    m / p.k[c]
}

/// Catches: the sample radii scaled (by 0.3 or 1.5, in `cpu::sample_pattern`, which the
/// GPU's pattern and the CPU twin share; planted, both fail here). A uniformly lit plane cannot see either (the self-normalised estimate is
/// E R_tot wherever its samples land); a quadratic irradiance can: with E(p) = |p|^2 on the
/// plane z = 0, B(x0) = R_tot (|x0|^2 + M2) exactly, M2 the truncated profile's normalised
/// second moment (radii x s give M2 x s^2: x0.09 or x2.25).
#[test]
fn quadratic_irradiance_measures_the_second_moment_on_a_stretched_plane() {
    for kind in [ProfileKind::Dipole, ProfileKind::Burley] {
        let p = profile(kind);
        // One plane per channel, sized to its radius R_c so that its texels are small
        // against its profile (the other channels' samples beyond R_c carry no weight in c).
        // 2:1 in UV: the walk has to unstretch x to land samples at the right millimetres.
        let size = 128u32;
        let planes: Vec<(f32, f32, TexGeometry, Vec<[f32; 4]>)> = (0..3)
            .map(|c| {
                let r = p.radius[c] as f32;
                let (w, h) = (6.0 * r, 3.0 * r);
                let geo = TexGeometry::build(&plane_mesh(w, h, 4).unwrap(), size, 1.0).unwrap();
                let e = geo
                    .pos
                    .iter()
                    .map(|q| {
                        let r2 = q[0] * q[0] + q[1] * q[1];
                        [r2, r2, r2, 1.0]
                    })
                    .collect();
                (w, h, geo, e)
            })
            .collect();
        let params = SamplerParams {
            samples: 256,
            ..Default::default()
        };
        let outs = common::with_gpu(|ctx| {
            planes
                .iter()
                .map(|(_, _, geo, e)| gpu_frame(ctx, geo, &p, params, &[], Some(e)))
                .collect::<vkshade::Result<Vec<_>>>()
        });
        for c in 0..3 {
            let (w, h, geo, e) = &planes[c];
            let out = &outs[c];
            let cpu = cpu::diffusion(geo, &Regions::from(&p), e, &params);
            let inner = interior(geo, *w, *h, p.radius[c] as f32 * 1.02);
            assert!(inner.len() > 1000, "{} interior texels", inner.len());
            let (mut gpu_sum, mut cpu_sum, mut d2, mut t2) = (0f64, 0f64, 0f64, 0f64);
            for &i in &inner {
                let x2 = e[i][0] as f64;
                let (g, b) = (out.diffuse[i][c] as f64, cpu[i][c] as f64);
                gpu_sum += g / p.r_tot[c] - x2;
                cpu_sum += b / p.r_tot[c] - x2;
                d2 += (g - b).powi(2);
                t2 += b * b;
            }
            // The same sampler on both sides; a sample may land in the neighbouring texel
            // where the driver's cos / sin rounds differently. A trig error e moves a sample
            // at the profile's radius (up to 43 texels here) by 43 e texels, so a fraction
            // p = 2 * 43 e of them changes texel, each changing E by 2 |x| d ~ 0.28 R^2
            // (d = 6R / 128): per texel 256 samples, a relative RMS of about
            // sqrt(256 p) * 0.28 / 256 = 0.0175 sqrt(p). Bound for e = 2^-20 (hardware
            // sin / cos; NVIDIA's is ~2^-21): 2e-4. Measured: lavapipe 1.7e-6, NVIDIA H200
            // 1.05e-5. The spec allows e = 2^-11, ~4e-3 here: a device using all of that
            // fails this bound although its sampler is right.
            let twin = (d2 / t2).sqrt();
            eprintln!("{kind:?} ch {c}: GPU vs CPU twin relative RMSE {twin:.2e}");
            assert!(
                twin < 2e-4,
                "{kind:?} ch {c}: GPU vs CPU twin relative RMSE {twin} (a sin / cos less \
                 precise than 2^-20 also gets here)"
            );
            let n = inner.len() as f64;
            // The sampler reads E at the nearest texel centre: an offset d uniform over the
            // texel (tx x ty mm) adds E[|d|^2] = (tx^2 + ty^2) / 12 on average (the cross
            // term 2 x.d averages out). It is 0.2% of M2 here, and only roughly uniform for
            // the shortest radii, which is why the planes are sized per channel.
            let (tx, ty) = ((w / size as f32) as f64, (h / size as f32) as f64);
            let want = second_moment(&p, c) + (tx * tx + ty * ty) / 12.0;
            for (side, got) in [("GPU", gpu_sum / n), ("CPU", cpu_sum / n)] {
                let rel = (got - want) / want;
                eprintln!(
                    "{kind:?} ch {c} {side}: mean B / R_tot - |x0|^2 = {got:.5} mm^2, M2 + lookup = {want:.5} ({rel:+.4})"
                );
                // Measured within 1.05% (-0.17% .. -1.05%; 256 stratified samples, each
                // texel's own rotation of the pattern); radii x 1.1 would move it by 21%.
                assert!(rel.abs() < 0.02, "{kind:?} ch {c} {side}: {got} vs {want}");
            }
        }
    }
}

/// A square grid of sources on the plane z = 0 (spacing `h` mm, centres at (i + 1/2) h for
/// |x|, |y| < `half`), lit by `e(x)`.
fn grid_sources(h: f64, half: f64, e: impl Fn(f64) -> f64) -> truth::Sources {
    let n = (half / h).ceil() as i64;
    let mut s = truth::Sources {
        pos: Vec::new(),
        edges: Vec::new(),
        e: Vec::new(),
        area: Vec::new(),
        normal: Vec::new(),
    };
    for j in -n..n {
        for i in -n..n {
            let (x, y) = ((i as f64 + 0.5) * h, (j as f64 + 0.5) * h);
            s.pos.push(DVec3::new(x, y, 0.0));
            s.edges.push((DVec3::X * h, DVec3::Y * h));
            s.e.push([e(x); 3]);
            s.area.push(h * h);
            s.normal.push(DVec3::Z);
        }
    }
    s
}

/// The untruncated radial CDF int_0^r 2 pi s Rd_c(s) ds (closed forms).
fn radial_cdf(p: &Profile, c: usize, r: f64) -> f64 {
    match p.kind {
        ProfileKind::Dipole => p.dipole[c].cdf(r),
        ProfileKind::Burley => p.burley[c].a * p.burley[c].p(r),
    }
}

/// B at signed distance `s` from the edge of a lit (E = 1, x < 0) half plane, untruncated:
/// int 2 pi r Rd(r) (the lit fraction of the circle of radius r about the receiver) dr, the
/// fraction acos(|s| / r) / pi on the far side of the edge. Midpoint rule in u = sqrt(r) up
/// to the radius holding all but 1e-7 of R_tot. Written here, apart from
/// `reference::sss::shadow_edge` (which truncates at the sampling radius).
fn half_plane(p: &Profile, c: usize, s: f64) -> f64 {
    let mut r_end = 1.0;
    while radial_cdf(p, c, r_end) < (1.0 - 1e-7) * p.r_tot[c] {
        r_end *= 1.5;
    }
    let n = 100_000;
    let du = r_end.sqrt() / n as f64;
    let mut b = 0.0;
    for i in 0..n {
        let u = (i as f64 + 0.5) * du;
        let r = u * u;
        let far = if r <= s.abs() {
            0.0
        } else {
            (s.abs() / r).acos() / std::f64::consts::PI
        };
        let lit = if s < 0.0 { 1.0 - far } else { far };
        b += 2.0 * std::f64::consts::PI * r * p.rd(c, r) * lit * 2.0 * u * du;
    }
    b
}

/// Truths tested against their analytic cases: the brute-force diffusion
/// (`reference::sss::brute_force`) on a plane of sources (0.1 mm texels out past every
/// channel's cutoff) against B = E R_tot under uniform light and against the half-plane
/// integral across a shadow edge (written in this test). Catches a truth that forgets a
/// texel's area, truncates a channel early, or mis-integrates the near field where Rd
/// peaks.
///
/// What it found: the truth's near-field rule (4 x 4 points per texel within 3 texels,
/// `Profile::rd_over_texel`) converges like h^2 for the dipole (finite at r = 0: blue
/// 3.9e-3 of R_tot at 0.2 mm texels, 7.2e-4 at 0.1 mm) but only like h / d for Burley, whose
/// Rd grows as 1 / r: the points miss part of the receiver's own texel, 1.8% low in blue at
/// 0.1 mm. The head tests judge the dipole.
#[test]
fn brute_force_truth_matches_the_plane_and_half_plane_in_closed_form() {
    for kind in [ProfileKind::Dipole, ProfileKind::Burley] {
        let p = profile(kind);
        let mut half = 1.0;
        for c in 0..3 {
            while radial_cdf(&p, c, half) < (1.0 - 1e-6) * p.r_tot[c] {
                half *= 1.2;
            }
        }
        // Receivers within 1 mm of the edge, the sources out to the cutoff beyond them.
        let half = half + 4.0;
        let h = 0.1;
        let receivers: Vec<DVec3> = (-8..8)
            .map(|k| DVec3::new((k as f64 + 0.5) * h, 0.5 * h, 0.0))
            .collect();
        let uniform = truth::brute_force(&grid_sources(h, half, |_| 1.0), &receivers, &p);
        let edge = truth::brute_force(
            &grid_sources(h, half, |x| if x < 0.0 { 1.0 } else { 0.0 }),
            &receivers,
            &p,
        );
        let (mut worst_uniform, mut worst_edge) = ([0f64; 3], [0f64; 3]);
        for (k, x) in receivers.iter().enumerate() {
            for c in 0..3 {
                let u = (uniform[k][c] - p.r_tot[c]) / p.r_tot[c];
                worst_uniform[c] = worst_uniform[c].max(u.abs());
                let want = half_plane(&p, c, x.x);
                let d = (edge[k][c] - want) / p.r_tot[c];
                worst_edge[c] = worst_edge[c].max(d.abs());
            }
        }
        eprintln!(
            "{kind:?} brute force, {half:.1} mm half plane: uniform off by {worst_uniform:?} of R_tot, edge off by {worst_edge:?}"
        );
        // Measured (0.1 mm texels, of R_tot, r / g / b): dipole 4.5e-5 / 1.8e-4 / 7.2e-4,
        // Burley 2.1e-3 / 8.0e-3 / 1.8e-2 (the 1 / r peak, see above); the edge as the
        // uniform plane. A lost texel area or a truncated channel is off by O(1).
        let bound = match kind {
            ProfileKind::Dipole => [1e-3; 3],
            ProfileKind::Burley => [3e-3, 1e-2, 2.5e-2],
        };
        for c in 0..3 {
            assert!(
                worst_uniform[c] < bound[c],
                "{kind:?} ch {c}: {worst_uniform:?}"
            );
            assert!(worst_edge[c] < bound[c], "{kind:?} ch {c}: {worst_edge:?}");
        }
    }
}

/// The BCN_Epileptic head with its rig, and its mesh posed at `frac` of the Epileptisch
/// animation on the CPU (`texspace::posed`).
fn posed_head(frac: f32) -> (vkshade::scene::Character, vkshade::scene::Mesh) {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("data/bcn_epileptic.glb");
    let ch = vkshade::app::sss::load_character(&path, Some("Head")).unwrap();
    let anim = ch.animation("Epileptisch").unwrap();
    let m = ch.rig.skinning_matrices(Some(anim), frac * anim.duration);
    let posed = vkshade::scene::texspace::posed(&ch.mesh, &m).unwrap();
    (ch, posed)
}

/// The largest |a - b| over `n` components of each pair.
fn max_diff(a: &[[f32; 4]], b: &[[f32; 4]], n: usize, keep: impl Fn(usize) -> bool) -> f32 {
    a.iter()
        .zip(b)
        .enumerate()
        .filter(|(i, _)| keep(*i))
        .map(|(_, (x, y))| (0..n).map(|c| (x[c] - y[c]).abs()).fold(0f32, f32::max))
        .fold(0f32, f32::max)
}

/// The per-frame geometry the GPU computes from posed vertex buffers (vertex frames, texel
/// position / normal / area, the surface walk's records, the refitted BVH) against the CPU's
/// rasterisation of the same pose, on a pose far from the bind pose; and the frame's outputs
/// against the CPU twin on that geometry (shadows through the refitted BVH against rays
/// through a BVH built for the pose), with two skin regions (multi-region skin): a
/// `pose_triangles.comp` that dropped the region from the records fails the record
/// comparison, and the diffusion then takes region 0's profile everywhere (fails the twin).
#[test]
fn posed_head_geometry_on_the_gpu_equals_the_cpu_rasterisation() {
    use vkshade::geom::bvh::{BvhTopology, refit, sah_cost};
    use vkshade::kernels::sss::walk::SurfaceWalk;
    use vkshade::kernels::sss::{PosedSource, contact::Contact};
    let size = 256;
    let (ch, posed) = posed_head(0.6);
    let rest = TexGeometry::build(&ch.mesh, size, 1000.0).unwrap();
    let geo = TexGeometry::build(&posed, size, 1000.0).unwrap();
    let extent = geo.extent_mm();
    let moved = posed
        .positions
        .iter()
        .zip(&ch.mesh.positions)
        .map(|(a, b)| (*a - *b).length() * 1000.0)
        .fold(0f32, f32::max);
    eprintln!("pose: vertices moved up to {moved:.0} mm (extent {extent:.0} mm)");
    assert!(moved > 0.2 * extent, "the pose is near the bind pose");
    let p = Profile::new(ProfileKind::Dipole, Material::SKIN1, 0.995).unwrap();
    // Two skin regions (the face's left and right of its mean x: skin 1 and skin 2), so that
    // the per-frame walk records must carry each triangle's region and the diffusion read it.
    let mean_x = rest.positions.iter().map(|v| v.x).sum::<f32>() / rest.positions.len() as f32;
    let split: Vec<u8> = rest
        .triangles
        .iter()
        .map(|t| {
            (t.iter().map(|&v| rest.positions[v as usize].x).sum::<f32>() >= 3.0 * mean_x) as u8
        })
        .collect();
    let skin2 = Profile::new(ProfileKind::Dipole, Material::SKIN2, 0.995).unwrap();
    let regions = Regions::new(vec![p.clone(), skin2], split.clone()).unwrap();
    let ones = split.iter().filter(|&&r| r == 1).count();
    assert!(
        ones > split.len() / 4 && ones < 3 * split.len() / 4,
        "{ones} of {}",
        split.len()
    );
    let lights = [Light::Directional {
        toward: Vec3::new(0.3, 0.4, 1.0).normalize(),
        e: 1.0,
    }];
    let params = SamplerParams {
        samples: 16,
        ..Default::default()
    };
    let (g, out, passes) = common::with_gpu(|ctx| {
        let mut setup = ctx.recorder("sss posed setup")?;
        // The posed buffers filled from the host (the CPU pose), so that the comparison is of
        // this kernel's passes alone.
        let src = PosedSource::upload(&mut setup, &posed.positions, &posed.normals)?;
        let kernel = SssKernel::new_posed(
            &mut setup,
            &rest,
            &ch.mesh.positions,
            &regions,
            params,
            src.buffers(1000.0),
        )?;
        setup.submit_and_wait()?;
        let mut rec = ctx.recorder("sss posed frame")?;
        kernel.record(&mut rec, &lights[..])?;
        let grb = kernel.read_back_geometry(&mut rec)?;
        let rb = kernel.read_back(&mut rec)?;
        let timings = rec.submit_and_wait()?;
        let passes: Vec<&str> = kernel.passes().iter().map(|p| p.name).collect();
        for name in &passes {
            assert!(timings.get(name).is_some(), "{name} not timed");
        }
        Ok((
            kernel.collect_geometry(&grb)?,
            kernel.collect(&rb)?,
            passes.len(),
        ))
    });
    // Pose vertices, pose triangles, BVH leaves and refit, lights, vertex light, the ray
    // list's reset, irradiance (which computes the texel geometry itself) and its rays,
    // diffusion.
    assert_eq!(passes, 10);
    // Vertex frames: the GPU scales the posed f32 by 1000 in f32, the CPU in f64 rounded
    // once to f32: the same rounding of the same exact product, so equal; the normal is
    // renormalised (1 ulp).
    let vf = cpu::vertex_frames(&geo);
    let dp = vf
        .iter()
        .zip(&g.vertex_frames)
        .map(|(a, b)| (Vec3::from_slice(&a[0][..3]) - Vec3::from_slice(&b[0][..3])).length())
        .fold(0f32, f32::max);
    let dn = vf
        .iter()
        .zip(&g.vertex_frames)
        .map(|(a, b)| (Vec3::from_slice(&a[1][..3]) - Vec3::from_slice(&b[1][..3])).length())
        .fold(0f32, f32::max);
    eprintln!("vertex frames: position off by {dp:e} mm, normal by {dn:e}");
    assert_eq!(dp, 0.0);
    assert!(dn < 1e-6);
    // Texels: same flags; positions interpolated in f32 from the f32 barycentrics (the CPU
    // in f64): a few ulp of the posed head's largest coordinate (the head is at standing
    // height, ~1.7 m: ulp 1.2e-4 mm), bound 4 ulp;
    // normals a few ulp of 1; areas: |e1 x e2| / |det| in f32 against the f64 Jacobian
    // product, relative 1e-4 (f32 cross products of thin triangles cancel).
    for i in 0..geo.texels() {
        assert_eq!(g.pos[i][3], geo.pos[i][3], "texel {i} flag");
    }
    let on = |i: usize| geo.pos[i][3] != 0.0;
    let pos_err = max_diff(&g.pos, &geo.pos, 3, on);
    let nrm_err = max_diff(&g.nrm, &geo.nrm, 3, on);
    let area_err = (0..geo.texels())
        .filter(|&i| geo.pos[i][3] == COVERED)
        .map(|i| (g.nrm[i][3] - geo.nrm[i][3]).abs() / geo.nrm[i][3].max(1e-12))
        .fold(0f32, f32::max);
    let gutter_area = (0..geo.texels())
        .filter(|&i| geo.pos[i][3] != 0.0 && geo.pos[i][3] != COVERED)
        .map(|i| g.nrm[i][3].abs())
        .fold(0f32, f32::max);
    eprintln!("texels: position {pos_err:e} mm, normal {nrm_err:e}, area rel {area_err:e}");
    let largest = geo
        .positions
        .iter()
        .map(|p| p.abs().max_element())
        .fold(0f32, f32::max);
    let ulp = largest * f32::EPSILON;
    assert!(
        pos_err <= 4.0 * ulp,
        "texel positions off by {pos_err} mm (ulp {ulp})"
    );
    assert!(nrm_err < 1e-5, "texel normals off by {nrm_err}");
    assert!(area_err < 1e-4, "texel areas off by {area_err} (relative)");
    assert_eq!(gutter_area, 0.0);
    // The walk's records: the frame, kinds and UVs; the crossing maps (texel units).
    let walk = SurfaceWalk::build(&geo);
    // (the walk's records carry no region; the kernel's hold each triangle's)
    let mut cpu_rec = walk.records();
    vkshade::kernels::sss::pack::region_records(&mut cpu_rec, &regions);
    assert!(
        cpu_rec
            .chunks(9)
            .zip(&split)
            .all(|(r, &s)| r[2][2] == s as u32)
    );
    assert_eq!(cpu_rec.len(), g.walk_records.len());
    let (mut shape_err, mut map_err, mut kinds_differ) = (0f32, 0f32, 0);
    for (t, wt) in walk.tris.iter().enumerate() {
        let (a, b) = (
            &cpu_rec[9 * t..9 * t + 9],
            &g.walk_records[9 * t..9 * t + 9],
        );
        assert_eq!(a[1], b[1], "triangle {t}: UV record");
        assert_eq!(a[2], b[2], "triangle {t}: UV record");
        kinds_differ += (a[0][3] != b[0][3]) as usize;
        if !(wt.shape[0] > 0.0 && wt.shape[2] > 0.0) {
            continue; // a degenerate triangle: its texels never leave it
        }
        // The record's frame is (1 / l1, x2, 1 / y2). 1 / l1: relative error. x2 = e2.x: in
        // units of the triangle's size (it may be ~0). 1 / y2: relative error times the
        // conditioning, since y2 = |cross(e1, e2)| / l1 of a sliver loses digits as
        // 1 / sin(angle at p0).
        let [l1, x2, y2] = wt.shape;
        let e2 = (x2 * x2 + y2 * y2).sqrt();
        let (size, sin) = (l1.max(e2), y2.abs() / e2);
        let v = |k: usize| (f32::from_bits(a[0][k]), f32::from_bits(b[0][k]));
        let ((il1, gl1), (cx2, gx2), (iy2, gy2)) = (v(0), v(1), v(2));
        shape_err = shape_err
            .max((il1 - gl1).abs() / il1.abs())
            .max((cx2 - gx2).abs() / size)
            .max((iy2 - gy2).abs() / iy2.abs() * sin);
        for r in 3..9 {
            for k in 0..4 {
                let (x, y) = (f32::from_bits(a[r][k]), f32::from_bits(b[r][k]));
                map_err = map_err.max((x - y).abs());
            }
        }
    }
    eprintln!(
        "walk: frame {shape_err:e} (relative, conditioned), crossing maps {map_err:e} texels, \
         {kinds_differ} \
         edge kinds differ"
    );
    assert_eq!(kinds_differ, 0);
    // Each of length, cross, dot and the divisions is within a few ulp on any conforming
    // device (the spec: 2.5 ulp for a division, 2 for inversesqrt, mul/add contracted or not),
    // about 10 operations deep: 64 ulp. Measured on lavapipe: 1.7 ulp (this form of the
    // metric has not run on a GPU yet; an earlier one in mixed units passed on an H200).
    assert!(
        shape_err < 64.0 * f32::EPSILON,
        "triangle frames off by {shape_err} (relative, conditioned)"
    );
    // The crossing maps are atlas positions (up to 256 texels): f32 unfolding against the
    // CPU's f64 crossing of its f32 unfolding, a few ulp of 256 (3e-5); bound 1e-3 texels,
    // which moves a sample's nearest texel only within 1e-3 of a texel border.
    assert!(map_err < 1e-3, "crossing maps off by {map_err} texels");
    // The BVH: the refit of the rest pose's topology, as the CPU twin computes it (the same
    // f32 arithmetic on the same vertices: equal).
    let top = BvhTopology::build(&rest.positions, &rest.triangles).unwrap();
    let (nodes, tris) = refit(&top, &geo.positions);
    assert_eq!(g.bvh_triangles, tris);
    assert_eq!(g.bvh_nodes.len(), nodes.len());
    for (a, b) in g.bvh_nodes.iter().zip(&nodes) {
        assert_eq!(a.map(f32::to_bits), b.map(f32::to_bits));
    }
    let fresh = Bvh::build(&geo.positions, &geo.triangles);
    eprintln!(
        "BVH: {} levels; SAH cost refitted {:.1}, built for the pose {:.1}",
        top.levels(),
        sah_cost(&nodes),
        sah_cost(&fresh.flat().0)
    );
    // The frame: shadows through the refitted BVH against rays through one built for the
    // pose (the CPU twin); a texel may flip where a ray grazes an edge (f32 rounding).
    let e = cpu::irradiance(&geo, &fresh, &lights, params.shadow_refine);
    let valid: Vec<usize> = (0..geo.texels()).filter(|&i| geo.pos[i][3] > 0.0).collect();
    let flipped = valid
        .iter()
        .filter(|&&i| (out.irradiance[i][0] - e[i][0]).abs() > 1e-4 * e[i][0].max(1e-3))
        .count();
    eprintln!(
        "shadows: {flipped} of {} texels differ from rays against the posed mesh",
        valid.len()
    );
    assert!(flipped * 1000 <= valid.len(), "{flipped} texels differ");
    // The diffusion against the CPU twin with the same walk and the contact entries the
    // kernel uses (built once, for the rest pose).
    let dg = cpu::DiffusionGeometry {
        walk,
        contact: Contact::build(&rest, &regions),
    };
    let b = cpu::diffusion_with(&dg, &geo, &regions, &out.irradiance, &params);
    for c in 0..3 {
        let (mut d2, mut t2) = (0f64, 0f64);
        for &i in &valid {
            d2 += ((out.diffuse[i][c] - b[i][c]) as f64).powi(2);
            t2 += (b[i][c] as f64).powi(2);
        }
        let rel = (d2 / t2).sqrt();
        eprintln!("diffusion channel {c}: GPU vs CPU twin rel RMSE {rel:e}");
        // As the static head (rel RMSE 0 measured there) plus samples whose landing texel
        // moves with the crossing maps' rounding (bounded above): 1e-4.
        assert!(rel < 1e-4, "channel {c}: relative RMSE {rel}");
    }
}

/// The accuracy target on the moving head, through the whole GPU path (the skinning
/// pass of `kernels::pose`, then this kernel's per-frame geometry, shadows through the
/// refitted BVH, irradiance, diffusion with the rest pose's contact entries): 512^2 x 64
/// samples at a pose far from the bind pose, relative RMSE <= 5% per channel and energy
/// within 2% of the brute force on that pose (every 3rd covered texel as a receiver, every
/// covered texel as a source). One pose here (the brute force takes most of a minute); the
/// three poses spread over the animation are `vkshade sss --anim Epileptisch --frames 3
/// --reference` (report `reference_poses`).
#[test]
fn posed_head_512_meets_the_accuracy_target_through_the_pose_kernel() {
    use vkshade::kernels::pose::{PoseKernel, Prepared};
    use vkshade::kernels::sss::PosedBuffers;
    let (ch, posed) = posed_head(0.6);
    let anim = ch.animation("Epileptisch").unwrap();
    let m = ch.rig.skinning_matrices(Some(anim), 0.6 * anim.duration);
    let rest = TexGeometry::build(&ch.mesh, 512, 1000.0).unwrap();
    let geo = TexGeometry::build(&posed, 512, 1000.0).unwrap();
    let p = Profile::new(ProfileKind::Dipole, Material::SKIN1, 0.995).unwrap();
    let lights = [Light::Directional {
        toward: Vec3::new(0.3, 0.4, 1.0).normalize(),
        e: 1.0,
    }];
    let params = SamplerParams {
        samples: 64,
        ..Default::default()
    };
    let out = common::with_gpu(|ctx| {
        let mut setup = ctx.recorder("sss posed setup")?;
        let prep = Prepared::new(&ch.mesh, ch.rig.joints.len())?;
        let pose = PoseKernel::new(&mut setup, &prep)?;
        let src = PosedBuffers {
            positions: pose.positions(),
            normals: pose.normals(),
            mm_per_unit: 1000.0,
        };
        let kernel = SssKernel::new_posed(&mut setup, &rest, &ch.mesh.positions, &p, params, src)?;
        setup.submit_and_wait()?;
        let mut rec = ctx.recorder("sss posed frame")?;
        pose.record(&mut rec, &m)?;
        kernel.record(&mut rec, &lights[..])?;
        let rb = kernel.read_back(&mut rec)?;
        rec.submit_and_wait()?;
        kernel.collect(&rb)
    });
    let err = against_brute_force(&geo, &out, &p);
    eprintln!("posed head 512^2 x 64 vs brute force: {err:?}");
    for c in 0..3 {
        assert!(err.rel_rmse[c] <= 0.05, "channel {c}: {err:?}");
        assert!(
            (err.energy_ratio[c] - 1.0).abs() <= 0.02,
            "channel {c}: {err:?}"
        );
    }
}

/// A smooth, non-uniform per-vertex rgb irradiance over a mesh (from its vertex normals and
/// positions; positive, of the order of the lights' E).
fn vertex_irradiance(geo: &TexGeometry) -> Vec<[f32; 4]> {
    geo.positions
        .iter()
        .zip(&geo.normals)
        .map(|(p, n)| {
            let s = (0.05 * p.x).sin() * (0.03 * p.y).cos();
            [
                0.6 + 0.4 * n.x,
                0.5 + 0.3 * n.y + 0.1 * s,
                0.4 + 0.3 * s,
                0.0,
            ]
        })
        .collect()
}

/// Records the upload of a per-vertex irradiance into a new buffer.
fn vertex_buffer(
    rec: &mut vkshade::gpu::Recorder,
    e: &[[f32; 4]],
) -> vkshade::Result<vkshade::gpu::Buffer> {
    use vkshade::gpu::{Buffer, BufferDesc};
    let ctx = rec.context();
    let b = Buffer::new(
        &ctx,
        "sss test vertex E",
        BufferDesc::storage(e.len() as u64 * 16),
    )?;
    rec.upload(&b, 0, e)?;
    Ok(b)
}

/// A per-vertex rgb irradiance (e.g. the environment shadowed by the character) added by the
/// irradiance pass and diffused as rgb: the GPU against its CPU twin on the head.
#[test]
fn a_per_vertex_irradiance_on_the_gpu_equals_the_cpu_twin() {
    let geo = head(256);
    let p = Profile::new(ProfileKind::Dipole, Material::SKIN1, 0.995).unwrap();
    let params = SamplerParams {
        samples: 32,
        ..Default::default()
    };
    let ve = vertex_irradiance(&geo);
    // No lights: the irradiance is the interpolated per-vertex E alone, with no shadow ray
    // that could flip at a grazing edge, so that the comparison is tight.
    let lights: [Light; 0] = [];
    let (out, passes) = common::with_gpu(|ctx| {
        let mut setup = ctx.recorder("sss env setup")?;
        let mut kernel = SssKernel::new(&mut setup, &geo, &p, params)?;
        let buffer = vertex_buffer(&mut setup, &ve)?;
        kernel.set_vertex_irradiance(&mut setup, Some(&buffer))?;
        setup.submit_and_wait()?;
        let mut out = None;
        run_frames(ctx, &kernel, [&lights[..]], 1, |r| {
            out = Some(r.output);
            Ok(())
        })?;
        Ok((out.unwrap(), kernel.passes().len()))
    });
    // Lights, vertex light, the per-vertex irradiance's copy, the ray list's reset,
    // irradiance and its rays, diffusion.
    assert_eq!(passes, 7);
    let e = cpu::irradiance_with_vertex(
        &geo,
        &Bvh::build(&geo.positions, &geo.triangles),
        &lights,
        params.shadow_refine,
        &ve,
    );
    let valid: Vec<usize> = (0..geo.texels()).filter(|&i| geo.pos[i][3] > 0.0).collect();
    let mut worst = 0f32;
    for i in 0..geo.texels() {
        if geo.pos[i][3] == 0.0 {
            assert_eq!(out.irradiance[i], [0.0; 4], "texel {i}: no surface");
            continue;
        }
        assert_eq!(out.irradiance[i][3], 1.0);
        for c in 0..3 {
            worst = worst.max((out.irradiance[i][c] - e[i][c]).abs() / e[i][c]);
        }
    }
    eprintln!("per-vertex irradiance: GPU vs CPU twin max relative difference {worst:e}");
    // Three products and two sums of positive f32 terms on each side, the same order; a
    // driver may fuse a product into a sum (one rounding fewer): a few ulp of the result at
    // most (ulp 1.2e-7 relative).
    assert!(
        worst <= 4.0 * f32::EPSILON,
        "max relative difference {worst}"
    );
    // Non-uniform: the channels differ and vary over the head.
    let spread = valid
        .iter()
        .map(|&i| out.irradiance[i][0])
        .fold((f32::MAX, 0f32), |(lo, hi), x| (lo.min(x), hi.max(x)));
    assert!(spread.1 > 1.5 * spread.0, "E red spans {spread:?}");
    // The rgb diffusion: the same sample pattern from the GPU's rgb irradiance (as the grey
    // path against its twin: measured 0, bound as there).
    let b = cpu::diffusion(&geo, &Regions::from(&p), &out.irradiance, &params);
    for c in 0..3 {
        let (mut d2, mut t2) = (0f64, 0f64);
        for &i in &valid {
            d2 += ((out.diffuse[i][c] - b[i][c]) as f64).powi(2);
            t2 += (b[i][c] as f64).powi(2);
        }
        let rel = (d2 / t2).sqrt();
        eprintln!("rgb diffusion channel {c}: GPU vs CPU twin rel RMSE {rel:e}");
        assert!(rel < 1e-5, "channel {c}: relative RMSE {rel}");
    }
}

/// A constant per-vertex irradiance adds exactly itself to every texel's irradiance, on the
/// posed head (the posed irradiance pass) with a shadowing light: the frame with it against
/// the frame without it, on the same kernel and pose.
#[test]
fn a_constant_per_vertex_irradiance_adds_exactly_itself() {
    use vkshade::kernels::sss::PosedSource;
    let size = 128;
    let (ch, posed) = posed_head(0.3);
    let rest = TexGeometry::build(&ch.mesh, size, 1000.0).unwrap();
    let p = Profile::new(ProfileKind::Dipole, Material::SKIN1, 0.995).unwrap();
    let lights = [Light::Directional {
        toward: Vec3::new(0.3, 0.4, 1.0).normalize(),
        e: 1.0,
    }];
    let params = SamplerParams {
        samples: 8,
        ..Default::default()
    };
    // Powers of two: with barycentrics that are multiples of 2^-16 (and w0 = 1 - w1 - w2
    // exact in f32), w0 a + w1 a + w2 a is exactly a, so the texel's E is the f32 sum
    // E_lights + a, bitwise.
    let a = [0.5f32, 1.0, 2.0];
    let ve = vec![[a[0], a[1], a[2], 0.0]; posed.positions.len()];
    let (without, with, passes) = common::with_gpu(|ctx| {
        let mut setup = ctx.recorder("sss env posed setup")?;
        let src = PosedSource::upload(&mut setup, &posed.positions, &posed.normals)?;
        let mut kernel = SssKernel::new_posed(
            &mut setup,
            &rest,
            &ch.mesh.positions,
            &p,
            params,
            src.buffers(1000.0),
        )?;
        let buffer = vertex_buffer(&mut setup, &ve)?;
        // Twice the environment, and a needed-segment bitmap marking every other word's 32
        // segments (set_needed_segments), a stand-in for the frame's `compose need`.
        let ve2: Vec<[f32; 4]> = ve.iter().map(|e| e.map(|x| 2.0 * x)).collect();
        let buffer2 = vertex_buffer(&mut setup, &ve2)?;
        let words = kernel.needed_segment_bytes() / 4;
        let bits: Vec<u32> = (0..words)
            .map(|w| if w % 2 == 0 { !0 } else { 0 })
            .collect();
        let needed = setup.buffer_with(
            "sss test needed segments",
            vkshade::gpu::BufferDesc::storage(words * 4),
            &bits,
        )?;
        let tiny = setup.buffer_with(
            "sss test tiny bitmap",
            vkshade::gpu::BufferDesc::storage(4),
            &[0u32],
        )?;
        setup.submit_and_wait()?;
        let frame = |kernel: &SssKernel| -> vkshade::Result<SssOutput> {
            let mut rec = ctx.recorder("sss env posed frame")?;
            kernel.record(&mut rec, &lights[..])?;
            let rb = kernel.read_back(&mut rec)?;
            rec.submit_and_wait()?;
            kernel.collect(&rb)
        };
        let without = frame(&kernel)?;
        // The bitmap restricts the diffusion of a per-vertex irradiance: refused before one.
        let e = kernel.set_needed_segments(Some(&needed)).unwrap_err();
        assert!(e.to_string().contains("set_vertex_irradiance"), "{e}");
        let mut rec = ctx.recorder("sss env set")?;
        kernel.set_vertex_irradiance(&mut rec, Some(&buffer))?;
        rec.submit_and_wait()?;
        let with = frame(&kernel)?;
        let passes = kernel.passes().len();
        let e = kernel.set_needed_segments(Some(&tiny)).unwrap_err();
        assert!(e.to_string().contains("bitmap of 4 bytes"), "{e}");
        // Restricted, then twice the environment (the bitmap stays with the kernel): the
        // marked segments take the new diffusion, the others keep the last one.
        kernel.set_needed_segments(Some(&needed))?;
        let mut rec = ctx.recorder("sss env set twice")?;
        kernel.set_vertex_irradiance(&mut rec, Some(&buffer2))?;
        rec.submit_and_wait()?;
        let culled = frame(&kernel)?;
        kernel.set_needed_segments(None)?;
        let full = frame(&kernel)?;
        let size = kernel.size();
        let (mut kept, mut fresh) = (0, 0);
        for i in 0..full.diffuse.len() {
            let (x, y) = ((i % size as usize) as u32, (i / size as usize) as u32);
            let seg = vkshade::kernels::sss::pack::needed_segment(x, y, size);
            if bits[(seg / 32) as usize] >> (seg % 32) & 1 == 1 {
                assert_eq!(culled.diffuse[i], full.diffuse[i], "texel {i}: marked");
                fresh += usize::from(full.diffuse[i] != with.diffuse[i]);
            } else {
                assert_eq!(culled.diffuse[i], with.diffuse[i], "texel {i}: not marked");
                kept += usize::from(full.diffuse[i] != with.diffuse[i]);
            }
        }
        assert!(
            fresh > 500 && kept > 500,
            "{fresh} marked, {kept} kept texels"
        );
        // Removed again: the grey path.
        let mut rec = ctx.recorder("sss env unset")?;
        kernel.set_vertex_irradiance(&mut rec, None)?;
        rec.submit_and_wait()?;
        let again = frame(&kernel)?;
        assert_eq!(again.irradiance, without.irradiance);
        Ok((without, with, passes))
    });
    // The posed frame's 10 and `sss vertex irradiance`.
    assert_eq!(passes, 11);
    let (mut covered, mut lit, mut shadowed) = (0, 0, 0);
    for i in 0..without.irradiance.len() {
        let (e0, e1) = (without.irradiance[i], with.irradiance[i]);
        if e0[3] == 0.0 {
            assert_eq!(e1, [0.0; 4], "texel {i}: no surface");
            continue;
        }
        covered += 1;
        lit += (e0[0] > 0.0) as usize;
        shadowed += (e0[0] == 0.0) as usize;
        for c in 0..3 {
            assert_eq!(
                e1[c].to_bits(),
                (e0[c] + a[c]).to_bits(),
                "texel {i} channel {c}: {} + {} gave {}",
                e0[c],
                a[c],
                e1[c]
            );
        }
    }
    assert!(
        covered > 1000 && lit > 100 && shadowed > 100,
        "{covered} {lit} {shadowed}"
    );
    // The diffusion is linear in E: a constant E spreads to itself times R_tot where every
    // sample finds surface; at least it adds light everywhere.
    for i in 0..with.diffuse.len() {
        if without.irradiance[i][3] != 0.0 && without.diffuse[i][3] > 0.0 {
            for c in 0..3 {
                assert!(with.diffuse[i][c] > without.diffuse[i][c], "texel {i}");
            }
        }
    }
}

/// The reach (`SssKernel::set_reach`): with needed segments set, the irradiance runs only on
/// the segments the needed segments' diffusion can read (the landings of its samples through
/// the surface walk, its contact entries), bounded each frame from the posed walk records.
/// On a posed head: the diffusion of the needed segments equals the unrestricted kernel's
/// bit for bit, on a first frame (the segments the reach leaves out hold no surface yet, so
/// a sample landing there would be lost and the texel would differ) and on a second frame
/// of another pose with another irradiance written into the same buffers (they hold the
/// first frame's); the reach leaves segments out
/// (else this would test nothing); the triangles it marks in the caller's bitmap (from bit
/// `first`) are exactly those with a texel in a reached segment; recording the front and the
/// back apart is recording the frame; misuse is refused. At 256^2 (atlas rows of whole
/// bitmap words: `sss reach list` takes a word at a time) and 200^2 (a segment at a time).
#[test]
fn the_reach_restricts_the_irradiance_and_leaves_the_diffusion_unchanged() {
    for size in [256, 200] {
        reach_at(size);
    }
}

fn reach_at(size: u32) {
    use vkshade::gpu::BufferDesc;
    use vkshade::kernels::sss::PosedSource;
    use vkshade::kernels::sss::gpu::ReachMarks;
    let (ch, posed) = posed_head(0.6);
    let (_, posed2) = posed_head(0.25);
    let rest = TexGeometry::build(&ch.mesh, size, 1000.0).unwrap();
    let p = Profile::new(ProfileKind::Dipole, Material::SKIN1, 0.995).unwrap();
    let lights = [Light::Directional {
        toward: Vec3::new(0.3, 0.4, 1.0).normalize(),
        e: 1.0,
    }];
    let params = SamplerParams::default();
    let ve = vertex_irradiance(&rest);
    let ve2: Vec<[f32; 4]> = ve.iter().map(|e| [e[2], e[0], e[1], 0.0]).collect();
    // The needed segments: a band of rows across the atlas.
    let row = size.div_ceil(8);
    let band = |seg: u32| (size / 3..size / 2).contains(&(seg / row));
    let first = 37u32;
    let triangles = rest.triangles.len() as u32;
    let out = common::with_gpu(|ctx| {
        let mut setup = ctx.recorder("sss reach setup")?;
        let src = PosedSource::upload(&mut setup, &posed.positions, &posed.normals)?;
        let make = |setup: &mut vkshade::gpu::Recorder| {
            SssKernel::new_posed(
                setup,
                &rest,
                &ch.mesh.positions,
                &p,
                params,
                src.buffers(1000.0),
            )
        };
        let mut full = make(&mut setup)?;
        let mut reach = make(&mut setup)?;
        let buffer = vertex_buffer(&mut setup, &ve)?;
        let words = reach.needed_segment_bytes() / 4;
        let bits: Vec<u32> = (0..words as u32)
            .map(|w| (0..32).filter(|b| band(w * 32 + b)).map(|b| 1 << b).sum())
            .collect();
        let needed = setup.buffer_with(
            "sss test needed band",
            BufferDesc::storage(words * 4),
            &bits,
        )?;
        let mark_words = (first + triangles).div_ceil(32) as u64;
        let marks = setup.buffer_with(
            "sss test reach marks",
            BufferDesc::storage(mark_words * 4),
            &vec![0u32; mark_words as usize],
        )?;
        let short =
            setup.buffer_with("sss test short marks", BufferDesc::storage(8), &[0u32; 2])?;
        // Refused before a per-vertex irradiance and needed segments.
        let e = reach.set_reach(Some(None)).unwrap_err();
        assert!(e.to_string().contains("set_needed_segments"), "{e}");
        full.set_vertex_irradiance(&mut setup, Some(&buffer))?;
        reach.set_vertex_irradiance(&mut setup, Some(&buffer))?;
        reach.set_needed_segments(Some(&needed))?;
        let e = reach
            .set_reach(Some(Some(ReachMarks {
                bitmap: &short,
                first,
            })))
            .unwrap_err();
        assert!(e.to_string().contains("bitmap of 8 bytes"), "{e}");
        reach.set_reach(Some(Some(ReachMarks {
            bitmap: &marks,
            first,
        })))?;
        setup.submit_and_wait()?;
        assert_eq!(reach.front_passes(), 8, "{:?}", reach.passes());
        let mut frames = Vec::new();
        for k in 0..2 {
            let mut rec = ctx.recorder("sss reach frame")?;
            if k == 1 {
                // Another pose and irradiance in the same buffers: the outputs keep the
                // first frame's values where this frame does not write.
                src.write(&mut rec, &posed2.positions, &posed2.normals)?;
                rec.upload(&buffer, 0, &ve2)?;
            }
            // Frame 0 through record, frame 1 as the front and the back apart.
            rec.fill_buffer(&marks, 0)?;
            if k == 0 {
                reach.record(&mut rec, &lights[..])?;
            } else {
                reach.record_front(&mut rec)?;
                reach.record_back(&mut rec, &lights[..])?;
            }
            full.record(&mut rec, &lights[..])?;
            let a = reach.read_back(&mut rec)?;
            let b = full.read_back(&mut rec)?;
            let list = reach.read_back_reach(&mut rec)?;
            let m = rec.read_back(&marks)?;
            rec.submit_and_wait()?;
            frames.push((
                reach.collect(&a)?,
                full.collect(&b)?,
                reach.reach_segments(&list)?,
                m.to_vec::<u32>()?,
            ));
        }
        Ok(frames)
    });
    let occupied: std::collections::HashSet<u32> = rest
        .texel_tri
        .iter()
        .enumerate()
        .filter(|(_, t)| t[0] < triangles)
        .map(|(i, _)| ((i as u32 % size) / 8) | ((i as u32 / size) << 16))
        .collect();
    for (k, (reached, full, list, marks)) in out.iter().enumerate() {
        let (mut compared, mut lit) = (0, 0);
        for i in 0..full.diffuse.len() {
            let (x, y) = ((i % size as usize) as u32, (i / size as usize) as u32);
            if !band(vkshade::kernels::sss::pack::needed_segment(x, y, size) as u32) {
                continue;
            }
            compared += 1;
            lit += usize::from(full.diffuse[i][0] > 0.0);
            assert_eq!(
                reached.diffuse[i], full.diffuse[i],
                "frame {k}, texel ({x}, {y}): the reach left out a texel its diffusion reads"
            );
        }
        assert!(
            compared > 1000 && lit > 500,
            "{compared} compared, {lit} lit"
        );
        let set: std::collections::HashSet<u32> = list.iter().copied().collect();
        assert_eq!(set.len(), list.len(), "a segment listed twice");
        assert!(set.is_subset(&occupied));
        let needed = occupied
            .iter()
            .filter(|&&s| band((s & 0xffff) + (s >> 16) * row))
            .count();
        assert!(
            set.len() > needed && set.len() + occupied.len() / 10 < occupied.len(),
            "frame {k}: {} reached of {} occupied segments, {needed} needed",
            set.len(),
            occupied.len()
        );
        // The marks' twin: triangles with a texel in a reached segment.
        let mut twin = vec![0u32; marks.len()];
        for (i, t) in rest.texel_tri.iter().enumerate() {
            let seg = ((i as u32 % size) / 8) | ((i as u32 / size) << 16);
            if t[0] < triangles && set.contains(&seg) {
                let b = first + t[0];
                twin[(b / 32) as usize] |= 1 << (b % 32);
            }
        }
        assert_eq!(marks, &twin, "frame {k}: the reach's triangle marks");
        eprintln!(
            "{size}^2, frame {k}: {} of {} occupied segments reached ({needed} needed), {} triangles marked",
            set.len(),
            occupied.len(),
            twin.iter().map(|w| w.count_ones()).sum::<u32>()
        );
    }
}
