//! Glossy SRBF transfer: the GPU against its CPU twin under validation, and the method against
//! the brute-force glossy truth on a real mesh and map.

mod common;

use glam::{Mat3, Vec3};
use vkshade::geom::Rng;
use vkshade::geom::brdf::Brdf;
use vkshade::geom::sg::{self, Lobe};
use vkshade::kernels::srbf::brdf_factors::BrdfFactors;
use vkshade::kernels::srbf::glossy::{GlossyTransfer, ViewBasis, ViewGrid};
use vkshade::kernels::srbf::glossy_gpu::{GlossyFrame, GlossyInputs, GlossyKernel};
use vkshade::kernels::srbf::sharp;
use vkshade::kernels::srbf::transfer::{Basis, Transfer};
use vkshade::kernels::{Kernel, run_frames};

/// Random lobes, a random glossy transfer (K = 96 basis functions; a 5 x 5 view grid, or 6
/// terms of the Phong BRDF's factorisation on a 16 x 16 table), random points in a box and
/// random unit normals.
struct Scene {
    lobes: Vec<Lobe>,
    transfer: GlossyTransfer,
    positions: Vec<Vec3>,
    normals: Vec<Vec3>,
}

const PHONG: Brdf = Brdf::Phong {
    exponent: 8.0,
    diffuse: 0.4,
    specular: 0.6,
};

fn factored() -> ViewBasis {
    ViewBasis::Brdf(Box::new(
        BrdfFactors::new(&PHONG, 6, ViewGrid { n: 16 }).unwrap(),
    ))
}

fn scene(vertices: usize, view: ViewBasis) -> Scene {
    let mut rng = Rng::new(19);
    let lobes = (0..40)
        .map(|_| Lobe {
            axis: vkshade::geom::uniform_sphere(rng.f32(), rng.f32()).to_array(),
            sharpness: 1.0 + 60.0 * rng.f32() * rng.f32(),
            amplitude: [rng.f32() * 3.0, rng.f32() * 2.0, rng.f32()],
        })
        .collect();
    let k = 96;
    let rows = vertices * view.views();
    let transfer = GlossyTransfer {
        rows: Transfer {
            basis: Basis::fibonacci(k),
            vertices: rows,
            coeffs: (0..rows * k).map(|_| rng.f32() * 0.1 - 0.03).collect(),
            projection_rel_l2: 0.0,
        },
        vertices,
        view,
        brdf: PHONG,
    };
    Scene {
        lobes,
        transfer,
        positions: (0..vertices)
            .map(|_| Vec3::new(rng.f32(), rng.f32(), rng.f32()) * 2.0 - 1.0)
            .collect(),
        normals: (0..vertices)
            .map(|_| vkshade::geom::uniform_sphere(rng.f32(), rng.f32()))
            .collect(),
    }
}

fn inputs(s: &Scene) -> GlossyInputs<'_> {
    GlossyInputs {
        lobes: &s.lobes,
        transfer: &s.transfer,
        positions: &s.positions,
        normals: &s.normals,
        compact: None,
    }
}

#[test]
fn glossy_gpu_matches_its_cpu_twin() {
    for view in [ViewBasis::Grid(ViewGrid { n: 5 }), factored()] {
        glossy_gpu_matches_its_cpu_twin_with(scene(1000, view));
    }
}

fn glossy_gpu_matches_its_cpu_twin_with(s: Scene) {
    // Cameras outside the box, one inside it (views below many vertices' horizons) and one
    // far away; rotations about +Y and an oblique axis.
    let frames: Vec<GlossyFrame> = [
        (0.0f32, Vec3::new(0.0, 0.5, 4.0)),
        (37.0, Vec3::new(3.0, -2.0, 1.0)),
        (131.0, Vec3::new(0.1, 0.2, -0.3)),
        (250.0, Vec3::new(-400.0, 90.0, 20.0)),
    ]
    .iter()
    .enumerate()
    .map(|(i, &(deg, camera))| GlossyFrame {
        rotation: if i % 2 == 0 {
            sg::rotation(Vec3::Y, deg)
        } else {
            sg::rotation(Vec3::new(1.0, 2.0, -0.5), deg)
        },
        albedo: [0.9, 0.7, 0.5],
        camera,
    })
    .collect();
    common::with_gpu(|ctx| {
        let mut setup = ctx.recorder("glossy setup")?;
        let kernel = GlossyKernel::new(&mut setup, &inputs(&s))?;
        setup.submit_and_wait()?;
        let names: Vec<&str> = kernel.passes().iter().map(|p| p.name).collect();
        assert_eq!(names, ["srbf lighting", "srbf glossy shade"]);
        let mut done = 0;
        run_frames(ctx, &kernel, &frames, 2, |r| {
            let want = inputs(&s).cpu_pipeline(&frames[r.index])?;
            // f32 on the GPU: each coefficient sums 40 products and each vertex 4 x 96 (grid)
            // or 6 x 96 terms (factored; each weight 4 taps of the table) of mixed sign; the
            // twin sums the same f32 inputs in f64. ~1e-6 per term of the output's scale, so
            // 1e-4 of the largest |value|. The tap weights are computed in f32 on both sides
            // from the same formulas; a vertex whose view falls exactly on a cell edge could
            // pick the neighbouring cell, which changes nothing (weight 0).
            let scale = want.iter().flatten().fold(0f64, |m, x| m.max(x.abs()));
            let worst = r
                .output
                .iter()
                .zip(&want)
                .flat_map(|(g, w)| (0..3).map(move |c| (g[c] as f64 - w[c]).abs()))
                .fold(0f64, f64::max);
            assert!(
                worst <= 1e-4 * scale,
                "frame {}: {worst} vs scale {scale}",
                r.index
            );
            done += 1;
            Ok(())
        })?;
        assert_eq!(done, frames.len());
        Ok(())
    });
}

#[test]
fn bad_glossy_inputs_are_refused() {
    let s = scene(10, ViewBasis::Grid(ViewGrid { n: 5 }));
    let mut short = s.transfer.clone();
    short.rows.coeffs.pop();
    let e = inputs(&s)
        .cpu_pipeline(&GlossyFrame {
            rotation: Mat3::IDENTITY,
            albedo: [1.0; 3],
            camera: Vec3::Z,
        })
        .map(|_| ())
        .and(
            GlossyInputs {
                transfer: &short,
                ..inputs(&s)
            }
            .check(),
        )
        .unwrap_err()
        .to_string();
    assert!(e.contains("glossy transfer"), "{e}");
    let e = GlossyInputs {
        positions: &s.positions[1..],
        ..inputs(&s)
    }
    .check()
    .unwrap_err()
    .to_string();
    assert!(e.contains("9 positions"), "{e}");
    let mut grid = s.transfer.clone();
    grid.view = ViewBasis::Grid(ViewGrid { n: 1 });
    assert!(grid.check().unwrap_err().to_string().contains("1 x 1"));
    // Factors of another BRDF than the transfer's, and a factor table cut short.
    let f = scene(10, factored());
    let mut other = f.transfer.clone();
    other.brdf = Brdf::Phong {
        exponent: 20.0,
        diffuse: 0.4,
        specular: 0.6,
    };
    let e = other.check().unwrap_err().to_string();
    assert!(e.contains("factors of"), "{e}");
    let mut short = f.transfer.clone();
    if let ViewBasis::Brdf(b) = &mut short.view {
        b.view.pop();
    }
    let e = short.check().unwrap_err().to_string();
    assert!(e.contains("BRDF factors"), "{e}");
    // Compact lobes: shaded with another BRDF than the transfer's, a visibility of other
    // vertices, a grid the visibility was not cast for, an invalid lobe, a NaN ray offset.
    {
        use vkshade::geom::visibility::direction_visibility;
        use vkshade::kernels::srbf::glossy_sharp::{CompactShadow, GlossyCompact};
        use vkshade::kernels::srbf::gpu::SunRays;
        let grid =
            vkshade::scene::envmap::EnvMap::from_texels(8, 4, vec![[0.0; 3]; 32], "g").unwrap();
        let dirs: Vec<Vec3> = grid.samples().iter().map(|x| x.0).collect();
        let bvh = vkshade::geom::Bvh::build(&[], &[]);
        let vis =
            |n: usize| direction_visibility(&s.positions[..n], &s.normals[..n], &bvh, &dirs, 0.0);
        let (ten, nine) = (vis(10), vis(9));
        let sun = [Lobe::new(Vec3::Y, 5000.0, [10.0; 3])];
        let bad_sun = [Lobe::new(Vec3::Y, f32::NAN, [10.0; 3])];
        let grid_of = |v| CompactShadow::Grid {
            visibility: v,
            width: 8,
            height: 4,
        };
        let ok = GlossyCompact {
            lobes: &sun,
            shadow: grid_of(&ten),
            brdf: PHONG,
            fit_width: sharp::DEFAULT_FIT_WIDTH,
        };
        assert!(
            GlossyInputs {
                compact: Some(ok),
                ..inputs(&s)
            }
            .check()
            .is_ok()
        );
        for (compact, says) in [
            (
                GlossyCompact {
                    brdf: Brdf::Diffuse,
                    ..ok
                },
                "compact lobes shaded with Diffuse",
            ),
            (
                GlossyCompact {
                    shadow: grid_of(&nine),
                    ..ok
                },
                "a visibility of 9 vertices",
            ),
            (
                GlossyCompact {
                    shadow: CompactShadow::Grid {
                        visibility: &ten,
                        width: 4,
                        height: 8,
                    },
                    ..ok
                },
                "is not the centre of texel",
            ),
            (
                GlossyCompact {
                    lobes: &bad_sun,
                    ..ok
                },
                "lobe 0 is not a valid SG",
            ),
            (
                GlossyCompact {
                    shadow: CompactShadow::Rays(SunRays {
                        positions: &s.positions,
                        bvh: &bvh,
                        offset: f32::NAN,
                    }),
                    ..ok
                },
                "ray offset NaN",
            ),
            (GlossyCompact { fit_width: 0, ..ok }, "fit width 0"),
        ] {
            let e = GlossyInputs {
                compact: Some(compact),
                ..inputs(&s)
            }
            .check()
            .unwrap_err()
            .to_string();
            assert!(e.contains(says), "{e}");
        }
    }
    common::with_gpu(|ctx| {
        let mut rec = ctx.recorder("bad glossy")?;
        let kernel = GlossyKernel::new(&mut rec, &inputs(&s))?;
        for frame in [
            GlossyFrame {
                rotation: Mat3::from_diagonal(Vec3::new(1.0, 1.0, -1.0)),
                albedo: [1.0; 3],
                camera: Vec3::Z,
            },
            GlossyFrame {
                rotation: Mat3::IDENTITY,
                albedo: [1.0; 3],
                camera: Vec3::new(f32::NAN, 0.0, 0.0),
            },
        ] {
            assert!(kernel.record(&mut rec, &frame).is_err());
        }
        drop(kernel);
        rec.submit_and_wait()?;
        Ok(())
    });
}

/// Relative L2 over points and channels: sqrt(sum |a - b|^2 / sum |b|^2).
fn rel_l2(a: &[[f64; 3]], b: &[[f64; 3]]) -> f64 {
    let (mut num, mut den) = (0.0, 0.0);
    for (x, y) in a.iter().zip(b) {
        for c in 0..3 {
            num += (x[c] - y[c]).powi(2);
            den += y[c].powi(2);
        }
    }
    (num / den).sqrt()
}

/// The glossy method (its CPU twin, which the GPU matches above) against the brute-force
/// glossy truth on the Stanford bunny (every 40th vertex shaded, 871 points, the whole mesh
/// occluding) under Blender's forest light (64 lobes; truth and transfer on the 64 x 32
/// texel directions), Phong exponent 8 with kd 0.3 / ks 0.7, for cameras whose views are not
/// grid nodes and rotations off the texel grid, with the error split by stage: fit (the truth
/// over the rasterised lobes against the truth) and transfer + view interpolation (the method
/// against that).
///
/// Measured (relative L2 over points and channels): 8 x 8 grid 5.5-5.8% (fit 1.4-1.5%,
/// transfer + view 5.3-5.9%); 12 x 12 grid 3.0-3.4% (transfer + view 3.0%); the default view
/// basis, 24 terms of the BRDF's factorisation, 2.4-2.6% (transfer + view 1.8-2.2%) with 24
/// rows per vertex against the 12 x 12 grid's 144. The 12 x 12 grid is held to the 5%
/// target and the 8 x 8 grid must be worse on every frame (the view interpolation is the
/// lever the grid size controls, as the h^2 lambda / 8 estimate says); the factored basis is
/// held to 3.2% and must beat the 12 x 12 grid on every frame (by 20-25% measured); the fit's
/// share is held to 2% (measured 1.5%, 64 lobes of a smooth map).
#[test]
fn glossy_bunny_against_the_brute_force_truth() {
    use vkshade::kernels::srbf::fit::{FitConfig, fit};
    use vkshade::reference::srbf::{rasterise_lobes, shade_glossy_truth};
    use vkshade::scene::envmap::EnvMap;
    let mesh = vkshade::scene::load(std::path::Path::new(vkshade::kernels::srbf::DEFAULT_MESH))
        .unwrap()
        .mesh;
    let env = EnvMap::load(std::path::Path::new(vkshade::kernels::srbf::DEFAULT_ENV)).unwrap();
    let lobes = fit(
        &env.downsampled(128).unwrap().samples(),
        &FitConfig {
            lobes: 64,
            ..FitConfig::default()
        },
    )
    .unwrap()
    .lobes;
    let dir_env = env.downsampled(64).unwrap();
    let pick: Vec<usize> = (0..mesh.positions.len()).step_by(40).collect();
    let points: Vec<Vec3> = pick.iter().map(|&v| mesh.positions[v]).collect();
    let normals: Vec<Vec3> = pick.iter().map(|&v| mesh.normals[v]).collect();
    let directions: Vec<Vec3> = dir_env.samples().iter().map(|s| s.0).collect();
    let (lo, hi) = mesh.bounds();
    let bvh = vkshade::geom::Bvh::build(&mesh.positions, &mesh.triangles);
    let vis = vkshade::geom::visibility::direction_visibility(
        &points,
        &normals,
        &bvh,
        &directions,
        1e-4 * (hi - lo).length(),
    );
    let centre = (lo + hi) * 0.5;
    let radius = (hi - lo).length();
    let brdf = Brdf::Phong {
        exponent: 8.0,
        diffuse: 0.3,
        specular: 0.7,
    };
    let mut errors: Vec<Vec<f64>> = Vec::new();
    let bases = [
        ViewBasis::Grid(ViewGrid { n: 8 }),
        ViewBasis::Grid(ViewGrid { n: 12 }),
        vkshade::kernels::srbf::glossy::DEFAULT_VIEW
            .build(&brdf)
            .unwrap(),
    ];
    for view in &bases {
        let n = view.describe();
        let mut per_frame = Vec::new();
        let t0 = std::time::Instant::now();
        let transfer = vkshade::kernels::srbf::glossy_transfer(
            &Basis::fibonacci(256),
            &brdf,
            view,
            &dir_env,
            &normals,
            &vis,
        )
        .unwrap();
        eprintln!(
            "{n}: projection {:.2?}, estimated rel L2 {:.4}",
            t0.elapsed(),
            transfer.rows.projection_rel_l2
        );
        let input = GlossyInputs {
            lobes: &lobes,
            transfer: &transfer,
            positions: &points,
            normals: &normals,
            compact: None,
        };
        for (deg, axis, cam) in [
            (0.0f32, Vec3::Y, Vec3::new(0.3, 0.2, 1.0)),
            (40.0, Vec3::Y, Vec3::new(-1.0, 0.4, 0.5)),
            (73.0, Vec3::X, Vec3::new(0.7, -0.3, -0.8)),
        ] {
            let frame = GlossyFrame {
                rotation: sg::rotation(axis, deg),
                albedo: [1.0; 3],
                camera: centre + cam.normalize() * 2.0 * radius,
            };
            let method = input.cpu_pipeline(&frame).unwrap();
            let truth = shade_glossy_truth(
                &dir_env,
                frame.rotation,
                &mesh,
                &points,
                &normals,
                &brdf,
                frame.camera,
                frame.albedo,
            )
            .unwrap();
            let raster = rasterise_lobes(&lobes, frame.rotation, &dir_env);
            let lobe_map = EnvMap::from_texels(
                dir_env.width,
                dir_env.height,
                raster.iter().map(|c| c.map(|x| x as f32)).collect(),
                "lobes",
            )
            .unwrap();
            let sg_truth = shade_glossy_truth(
                &lobe_map,
                Mat3::IDENTITY,
                &mesh,
                &points,
                &normals,
                &brdf,
                frame.camera,
                frame.albedo,
            )
            .unwrap();
            let (e, fit_share) = (rel_l2(&method, &truth), rel_l2(&sg_truth, &truth));
            eprintln!(
                "{n}, {axis}:{deg}: method vs truth {e:.4}; fit {fit_share:.4}; transfer + \
                 view {:.4}",
                rel_l2(&method, &sg_truth)
            );
            assert!(fit_share < 0.02, "fit share {fit_share}");
            per_frame.push(e);
        }
        errors.push(per_frame);
    }
    for ((coarse, fine), factored) in errors[0].iter().zip(&errors[1]).zip(&errors[2]) {
        assert!(*fine <= 0.05, "12 x 12 grid: {fine}");
        assert!(
            coarse > fine,
            "8 x 8 grid {coarse} not worse than 12 x 12 {fine}"
        );
        assert!(
            *factored <= 0.032 && factored < fine,
            "24 BRDF terms: {factored} (12 x 12 grid: {fine})"
        );
    }
}

/// CTA-compressed glossy transfer: the GPU's four passes against their CPU twin, and the
/// twin (per-cluster tables, interpolated view factor) against shading the densely
/// reconstructed transfer matrices T_v = sum u G W L with the uncompressed path.
#[test]
fn cta_gpu_matches_its_twin_and_the_dense_reconstruction() {
    // r_v 9: two coefficient texels, the cluster id in the second's free component; r_v 7:
    // one texel, full, the cluster id read from its buffer.
    for (view, rv) in [(ViewBasis::Grid(ViewGrid { n: 5 }), 9), (factored(), 7)] {
        cta_gpu_matches_its_twin_with(scene(600, view), rv);
    }
}

fn cta_gpu_matches_its_twin_with(s: Scene, rv: usize) {
    use vkshade::kernels::srbf::cta::{Cta, CtaConfig};
    use vkshade::kernels::srbf::cta_gpu::{CtaInputs, CtaKernel};
    let t = &s.transfer;
    let cta = Cta::compress(
        &t.rows.basis,
        &t.rows.coeffs,
        t.vertices,
        t.views(),
        &CtaConfig {
            clusters: 5,
            // r_l 7 pads the light ranks' last texel quad.
            ranks: [rv, 5.min(t.views()), 7],
            iterations: 1,
            ..CtaConfig::default()
        },
    )
    .unwrap();
    // The runtime streams the coefficients in half precision (`Cta::coeff`): the dense
    // reconstruction is built from a copy rounded so, while the twin and the GPU get the
    // model's f32 values and must round them themselves.
    let mut rounded = cta.clone();
    rounded
        .coeffs
        .iter_mut()
        .for_each(|u| *u = vkshade::io::f16::half_round(*u));
    assert_ne!(rounded.coeffs, cta.coeffs, "nothing to round");
    let dense = GlossyTransfer {
        rows: Transfer {
            coeffs: (0..t.vertices)
                .flat_map(|v| rounded.reconstruct(v))
                .map(|x| x as f32)
                .collect(),
            ..t.rows.clone()
        },
        ..t.clone()
    };
    let inputs = CtaInputs {
        lobes: &s.lobes,
        transfer: &cta,
        view: &t.view,
        positions: &s.positions,
        normals: &s.normals,
        compact: None,
    };
    let frames: Vec<GlossyFrame> = [
        (0.0f32, Vec3::new(0.0, 0.5, 4.0)),
        (77.0, Vec3::new(-3.0, 1.0, 0.2)),
    ]
    .iter()
    .map(|&(deg, camera)| GlossyFrame {
        rotation: sg::rotation(Vec3::new(0.3, 1.0, 0.1), deg),
        albedo: [0.9, 0.7, 0.5],
        camera,
    })
    .collect();
    let max_abs = |v: &[[f64; 3]]| v.iter().flatten().fold(0f64, |m, x| m.max(x.abs()));
    let worst = |a: &[[f64; 3]], b: &[[f64; 3]]| {
        a.iter()
            .zip(b)
            .flat_map(|(x, y)| (0..3).map(move |c| (x[c] - y[c]).abs()))
            .fold(0f64, f64::max)
    };
    for f in &frames {
        let twin = inputs.cpu_pipeline(f).unwrap();
        let lit = GlossyInputs {
            lobes: &s.lobes,
            transfer: &dense,
            positions: &s.positions,
            normals: &s.normals,
            compact: None,
        }
        .cpu_pipeline(f)
        .unwrap();
        // The same f32 factors summed in a different order (f64), the dense rows rounded to
        // f32 once: 1e-5 of the largest value.
        let e = worst(&twin, &lit);
        assert!(e <= 1e-5 * max_abs(&lit), "{e} vs {}", max_abs(&lit));
    }
    common::with_gpu(|ctx| {
        let mut setup = ctx.recorder("cta setup")?;
        let kernel = CtaKernel::new(&mut setup, &inputs)?;
        setup.submit_and_wait()?;
        let names: Vec<&str> = kernel.passes().iter().map(|p| p.name).collect();
        assert_eq!(
            names,
            [
                "srbf lighting",
                "srbf cta light",
                "srbf cta project",
                "srbf cta shade"
            ]
        );
        let mut done = 0;
        run_frames(ctx, &kernel, &frames, 2, |r| {
            let want = inputs.cpu_pipeline(&frames[r.index])?;
            let got: Vec<[f64; 3]> = r.output.iter().map(|c| c.map(|x| x as f64)).collect();
            // f32 on the GPU over sums of 96 (light), 7 (core), 4 x 5 (view) and 9 x 5 terms:
            // ~1e-6 per term of the output's scale; 1e-4 of the largest |value|.
            let e = worst(&got, &want);
            assert!(e <= 1e-4 * max_abs(&want), "frame {}: {e}", r.index);
            done += 1;
            Ok(())
        })?;
        assert_eq!(done, frames.len());
        Ok(())
    });
}

/// Compact lobes on the glossy path (pass `srbf glossy sharp`) against the CPU twin, for both
/// shadowings (the grid's texel bit, a shadow ray at the exact axis) and both transfers
/// (uncompressed, CTA): random points and normals under random occluding triangles, four
/// suns. A vertex may differ where the GPU's ray (or its texel lookup, atan in f32) decides a
/// bit the other way than the twin's, a few in a thousand; every other vertex matches to
/// 1e-4 of the scale. The compact part must matter (>= 20% of the radiance's scale) and be
/// shadowed at some vertices, so that the comparison means something.
#[test]
fn glossy_compact_lobes_match_the_cpu_twin() {
    use vkshade::geom::Bvh;
    use vkshade::geom::visibility::direction_visibility;
    use vkshade::kernels::srbf::cta::{Cta, CtaConfig};
    use vkshade::kernels::srbf::cta_gpu::{CtaInputs, CtaKernel};
    use vkshade::kernels::srbf::glossy_sharp::{CompactShadow, GlossyCompact};
    use vkshade::kernels::srbf::gpu::SunRays;
    use vkshade::scene::envmap::EnvMap;
    let s = scene(800, factored());
    let mut rng = Rng::new(23);
    let n = s.positions.len();
    let mut points = s.positions.clone();
    let mut triangles = Vec::new();
    for t in 0..12u32 {
        let c = Vec3::new(rng.f32(), rng.f32(), rng.f32()) * 3.0 - 1.5;
        for _ in 0..3 {
            points.push(c + Vec3::new(rng.f32(), rng.f32(), rng.f32()) * 1.2 - 0.6);
        }
        let first = n as u32 + 3 * t;
        triangles.push([first, first + 1, first + 2]);
    }
    let bvh = Bvh::build(&points, &triangles);
    let grid = EnvMap::from_texels(64, 32, vec![[0.0; 3]; 64 * 32], "grid").unwrap();
    let dirs: Vec<Vec3> = grid.samples().iter().map(|x| x.0).collect();
    let vis = direction_visibility(&s.positions, &s.normals, &bvh, &dirs, 1e-4);
    // Two resolved lamps (spread over four grid taps each) and two suns (one tap).
    let suns: Vec<Lobe> = [1200.0, 1600.0, 9000.0, 10000.0]
        .iter()
        .map(|&sharpness| {
            let axis = vkshade::geom::uniform_sphere(rng.f32(), rng.f32());
            Lobe::new(axis, sharpness, [9e3, 6e3, 3e3])
        })
        .collect();
    assert_eq!(
        sharp::points(&suns, sharp::DEFAULT_FIT_WIDTH),
        [false, false, true, true]
    );
    // The occluders shadow the suns: of the (vertex, sun) pairs facing the sun, the twin's
    // rays find some blocked (and most not).
    let taps = vkshade::kernels::srbf::sharp::ray_taps(&suns, Mat3::IDENTITY);
    let bits = vkshade::kernels::srbf::sharp::ray_bits(&taps, &s.positions, &s.normals, &bvh, 1e-4);
    let facing: usize = (0..n)
        .map(|v| {
            taps.iter()
                .filter(|t| s.normals[v].dot(t.dir) > 0.0)
                .count()
        })
        .sum();
    let lit: usize = bits.iter().map(|b| b.count_ones() as usize).sum();
    assert!(
        lit * 20 < facing * 19 && lit * 2 > facing,
        "{lit} of {facing}"
    );
    let t = &s.transfer;
    let cta = Cta::compress(
        &t.rows.basis,
        &t.rows.coeffs,
        t.vertices,
        t.views(),
        &CtaConfig {
            clusters: 4,
            ranks: [4, 6, 8],
            iterations: 1,
            ..CtaConfig::default()
        },
    )
    .unwrap();
    let frames: Vec<GlossyFrame> = [
        (0.0f32, Vec3::new(0.0, 0.5, 4.0)),
        (61.0, Vec3::new(-3.0, 1.0, 0.2)),
        (200.0, Vec3::new(0.1, 0.2, -0.3)),
    ]
    .iter()
    .map(|&(deg, camera)| GlossyFrame {
        rotation: sg::rotation(Vec3::new(0.3, 1.0, -0.6), deg),
        albedo: [0.8, 0.6, 0.4],
        camera,
    })
    .collect();
    let shadows = [
        CompactShadow::Grid {
            visibility: &vis,
            width: 64,
            height: 32,
        },
        CompactShadow::Rays(SunRays {
            positions: &s.positions,
            bvh: &bvh,
            offset: 1e-4,
        }),
    ];
    common::with_gpu(|ctx| {
        for shadow in shadows {
            let compact = GlossyCompact {
                lobes: &suns,
                shadow,
                brdf: PHONG,
                fit_width: sharp::DEFAULT_FIT_WIDTH,
            };
            let dense = GlossyInputs {
                compact: Some(compact),
                ..inputs(&s)
            };
            let tensor = CtaInputs {
                lobes: &s.lobes,
                transfer: &cta,
                view: &t.view,
                positions: &s.positions,
                normals: &s.normals,
                compact: Some(compact),
            };
            let mut setup = ctx.recorder("glossy compact setup")?;
            let k1 = GlossyKernel::new(&mut setup, &dense)?;
            let k2 = CtaKernel::new(&mut setup, &tensor)?;
            setup.submit_and_wait()?;
            assert_eq!((k1.compact_count(), k2.compact_count()), (4, 4));
            for names in [
                k1.passes().iter().map(|p| p.name).collect::<Vec<_>>(),
                k2.passes().iter().map(|p| p.name).collect(),
            ] {
                assert_eq!(names.last(), Some(&"srbf glossy sharp"), "{names:?}");
            }
            let (mut off, mut total) = (0usize, 0usize);
            let mut check = |got: &[[f32; 3]], frame: &GlossyFrame, twin: Vec<[f64; 3]>| {
                // What the compact lobes add, alone.
                let mut only = vec![[0f64; 3]; n];
                compact.add(frame, &s.positions, &s.normals, &mut only)?;
                let scale = twin.iter().flatten().fold(0f64, |m, x| m.max(x.abs()));
                let part = only.iter().flatten().fold(0f64, |m, x| m.max(x.abs()));
                assert!(part >= 0.2 * scale, "compact part {part} of {scale}");
                for (g, w) in got.iter().zip(&twin) {
                    total += 1;
                    if (0..3).any(|c| (g[c] as f64 - w[c]).abs() > 1e-4 * scale) {
                        off += 1;
                    }
                }
                vkshade::Result::Ok(())
            };
            run_frames(ctx, &k1, &frames, 2, |r| {
                let f = &frames[r.index];
                check(&r.output, f, dense.cpu_pipeline(f)?)
            })?;
            run_frames(ctx, &k2, &frames, 2, |r| {
                let f = &frames[r.index];
                check(&r.output, f, tensor.cpu_pipeline(f)?)
            })?;
            eprintln!("glossy compact: {off} of {total} vertex-frames off");
            assert!(off * 200 <= total, "{off} of {total} vertex-frames differ");
        }
        Ok(())
    });
}
