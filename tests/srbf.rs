//! The SRBF kernel on the GPU against the same pipeline on the CPU (f64), under validation.

mod common;

use glam::{Mat3, Vec3};
use vkshade::geom::Rng;
use vkshade::geom::sg::{self, Lobe};
use vkshade::geom::visibility::Visibility;
use vkshade::io::f16::half_round;
use vkshade::kernels::srbf::cpca::{Cpca, CpcaConfig};
use vkshade::kernels::srbf::gpu::{CompactInputs, SrbfFrame, SrbfInputs, SrbfKernel};
use vkshade::kernels::srbf::sharp;
use vkshade::kernels::srbf::transfer::{Basis, Transfer};
use vkshade::kernels::{Kernel, run_frames};
use vkshade::scene::envmap::EnvMap;

struct Scene {
    lobes: Vec<Lobe>,
    transfer: Cpca,
    compact: Option<Compact>,
}

/// What compact lobes are shaded from: a 64 x 32 direction grid, random normals, and the
/// visibility of the grid's directions from random points among random occluding triangles
/// (so that the bits hold both values).
struct Compact {
    grid: EnvMap,
    normals: Vec<Vec3>,
    vis: Visibility,
}

impl Scene {
    /// The same scene with three compact lobes added (sharpness 800-9000, far above 32 x the
    /// basis's 8, each holding several % of the energy) and the data to shade them: a point
    /// source (above the fit's cap wherever it points) and two resolved lobes.
    fn with_compact(mut self) -> Scene {
        let mut rng = Rng::new(11);
        for (sharpness, amp) in [(9000.0, 27000.0), (1500.0, 3000.0), (800.0, 2500.0)] {
            let axis = vkshade::geom::uniform_sphere(rng.f32(), rng.f32());
            self.lobes.push(Lobe {
                axis: axis.to_array(),
                sharpness,
                amplitude: [amp, 0.7 * amp, 0.4 * amp],
            });
        }
        let n = self.transfer.vertices;
        let grid = EnvMap::from_texels(64, 32, vec![[0.0; 3]; 64 * 32], "grid").unwrap();
        let dirs: Vec<Vec3> = grid.samples().iter().map(|s| s.0).collect();
        let normals: Vec<Vec3> = (0..n)
            .map(|_| vkshade::geom::uniform_sphere(rng.f32(), rng.f32()))
            .collect();
        let positions: Vec<Vec3> = (0..n)
            .map(|_| Vec3::new(rng.f32(), rng.f32(), rng.f32()) * 2.0 - 1.0)
            .collect();
        let mut tri_points = Vec::new();
        let mut triangles = Vec::new();
        for t in 0..12u32 {
            let c = Vec3::new(rng.f32(), rng.f32(), rng.f32()) * 3.0 - 1.5;
            for _ in 0..3 {
                tri_points.push(c + Vec3::new(rng.f32(), rng.f32(), rng.f32()) * 1.2 - 0.6);
            }
            triangles.push([3 * t, 3 * t + 1, 3 * t + 2]);
        }
        let bvh = vkshade::geom::Bvh::build(&tri_points, &triangles);
        let vis = vkshade::geom::visibility::direction_visibility(
            &positions, &normals, &bvh, &dirs, 1e-4,
        );
        self.compact = Some(Compact { grid, normals, vis });
        self
    }
}

/// Random lobes and a random clustered-PCA transfer (`components` 0: the uncompressed form).
fn scene(lobes: usize, k: usize, vertices: usize, clusters: usize, components: usize) -> Scene {
    let mut rng = Rng::new(7);
    let lobes = (0..lobes)
        .map(|_| {
            let axis = vkshade::geom::uniform_sphere(rng.f32(), rng.f32());
            Lobe {
                axis: axis.to_array(),
                sharpness: 1.0 + 60.0 * rng.f32() * rng.f32(),
                amplitude: [rng.f32() * 3.0, rng.f32() * 2.0, rng.f32()],
            }
        })
        .collect();
    let basis = Basis {
        axes: sg::fibonacci_sphere(k),
        sharpness: 8.0,
    };
    let coeffs: Vec<f32> = (0..vertices * k).map(|_| rng.f32() * 0.1 - 0.02).collect();
    let transfer = if components == 0 {
        Cpca::exact(&Transfer {
            basis,
            vertices,
            coeffs,
            projection_rel_l2: 0.0,
        })
    } else {
        // Uneven cluster sizes (some under one workgroup, one empty), rows and weights of
        // mixed sign.
        Cpca {
            basis,
            vertices,
            clusters,
            components,
            cluster_of: (0..vertices)
                .map(|_| {
                    ((rng.f32() * rng.f32() * (clusters - 1) as f32) as u32)
                        .min(clusters as u32 - 2)
                })
                .collect(),
            rows: (0..clusters * (components + 1) * k)
                .map(|_| rng.f32() * 0.1 - 0.03)
                .collect(),
            weights: (0..vertices * components)
                .map(|_| rng.f32() * 2.0 - 1.0)
                .collect(),
            rel_l2: 0.0,
        }
    };
    Scene {
        lobes,
        transfer,
        compact: None,
    }
}

/// The pipeline in f64: c_k = sum_j a_j <G_j(R xi_j), G_k>,
/// L_v = albedo sum_k (m_ck + sum_i w_vi a_cik) c_k, with the weights w at half precision.
/// Compact lobes (selected by `sharp::split`, unit-tested in the library) add, per vertex,
/// albedo / pi * sum_j amp_j integral(lambda_j) sum_p share_jp V(p) max(0, n . w_p) over
/// their taps ([`compact_taps`]): w_p the texel centre directions.
fn cpu(s: &Scene, frame: &SrbfFrame) -> Vec<[f64; 3]> {
    let t = &s.transfer;
    let (smooth, compact) = match &s.compact {
        Some(_) => sharp::split(&s.lobes, t.basis.sharpness, sharp::DEFAULT_FACTOR, 4),
        None => (s.lobes.clone(), Vec::new()),
    };
    let (k, m) = (t.basis.len(), t.components);
    let coeffs: Vec<[f64; 3]> = t
        .basis
        .axes
        .iter()
        .map(|eta| {
            let mut c = [0f64; 3];
            for l in &smooth {
                let axis = (frame.rotation * l.axis()).normalize();
                let ip = sg::inner_product_f64(
                    axis.as_dvec3(),
                    l.sharpness as f64,
                    eta.as_dvec3(),
                    t.basis.sharpness as f64,
                );
                for (c, a) in c.iter_mut().zip(l.amplitude) {
                    *c += a as f64 * ip;
                }
            }
            c
        })
        .collect();
    (0..t.vertices)
        .map(|v| {
            let rows = &t.rows[t.cluster_of[v] as usize * (m + 1) * k..];
            let w = &t.weights[v * m..(v + 1) * m];
            let mut out = [0f64; 3];
            for (i, c) in coeffs.iter().enumerate() {
                let mut tv = rows[i] as f64;
                for (j, wj) in w.iter().enumerate() {
                    // The GPU holds the weights in half precision.
                    tv += half_round(*wj) as f64 * rows[(j + 1) * k + i] as f64;
                }
                for (o, c) in out.iter_mut().zip(c) {
                    *o += tv * c;
                }
            }
            if let Some(cs) = &s.compact {
                let n = cs.normals[v].as_dvec3();
                for l in &compact {
                    for (x, y, share) in compact_taps(&cs.grid, l, frame.rotation) {
                        let p = (y * cs.grid.width + x) as usize;
                        if cs.vis.visible(v, p) {
                            let cos = n.dot(cs.grid.direction(x, y).as_dvec3()).max(0.0);
                            let g = sg::integral(l.sharpness as f64) / std::f64::consts::PI;
                            for (o, a) in out.iter_mut().zip(l.amplitude) {
                                *o += a as f64 * g * share * cos;
                            }
                        }
                    }
                }
            }
            [0, 1, 2].map(|ch| out[ch] * frame.albedo[ch] as f64)
        })
        .collect()
}

/// Compact lobe `l` rotated by `rotation` on `grid`, as (column, row, share of its integral):
/// a point source ([`sharp::is_point`]) whole at the texel of its axis; a resolved lobe over
/// the 2 x 2 texels whose centres surround its axis, each share its integral over the texel
/// (8 x 8 sub-samples, solid-angle weighted, f64), renormalised.
fn compact_taps(grid: &EnvMap, l: &Lobe, rotation: Mat3) -> Vec<(u32, u32, f64)> {
    let axis = (rotation * l.axis()).normalize();
    let (x0, y0) = grid.texel_of(axis);
    if sharp::is_point(l, sharp::DEFAULT_FIT_WIDTH) {
        return vec![(x0, y0, 1.0)];
    }
    let (w, h) = (grid.width as i64, grid.height as i64);
    // The side of the texel's centre the axis lies on, in u and in v.
    let a = axis.as_dvec3();
    let u = 0.5 + a.x.atan2(-a.z) / std::f64::consts::TAU;
    let v = a.x.hypot(a.z).atan2(a.y) / std::f64::consts::PI;
    let dx = if u * w as f64 - (x0 as f64) < 0.5 {
        -1
    } else {
        1
    };
    let dy = if v * h as f64 - (y0 as f64) < 0.5 {
        -1
    } else {
        1
    };
    let mut cells = Vec::new();
    for (sx, sy) in [(0, 0), (dx, 0), (0, dy), (dx, dy)] {
        let y = y0 as i64 + sy;
        if !(0..h).contains(&y) {
            continue;
        }
        let x = (x0 as i64 + sx).rem_euclid(w);
        let mut e = 0.0;
        for j in 0..8 {
            for i in 0..8 {
                let u = (x as f64 + (i as f64 + 0.5) / 8.0) / w as f64;
                let v = (y as f64 + (j as f64 + 0.5) / 8.0) / h as f64;
                let d = vkshade::scene::envmap::direction_of(u, v);
                let g = (l.sharpness as f64 * (a.dot(d) - 1.0)).exp();
                e += g * (std::f64::consts::PI * v).sin();
            }
        }
        cells.push((x as u32, y as u32, e));
    }
    let total: f64 = cells.iter().map(|c| c.2).sum();
    cells
        .into_iter()
        .map(|(x, y, e)| (x, y, e / total))
        .collect()
}

fn inputs(s: &Scene) -> SrbfInputs<'_> {
    let i = SrbfInputs::new(&s.lobes, &s.transfer);
    match &s.compact {
        Some(c) => i.with_compact(CompactInputs {
            visibility: &c.vis,
            normals: &c.normals,
            width: c.grid.width,
            height: c.grid.height,
            factor: sharp::DEFAULT_FACTOR,
            max_lobes: 4,
            fit_width: sharp::DEFAULT_FIT_WIDTH,
        }),
        None => i,
    }
}

#[test]
fn gpu_rotation_and_shading_match_the_cpu_pipeline() {
    // Compressed (9 clusters x 6 components: padded groups and slots) and uncompressed,
    // and compressed with compact lobes shaded from the visibility.
    gpu_matches_cpu(&scene(48, 300, 2000, 9, 6));
    gpu_matches_cpu(&scene(48, 300, 2000, 1, 0));
    gpu_matches_cpu(&scene(48, 300, 2000, 9, 6).with_compact());
}

fn gpu_matches_cpu(s: &Scene) {
    let frames: Vec<SrbfFrame> = [0.0f32, 30.0, 97.0, 180.0, 271.0]
        .iter()
        .enumerate()
        .map(|(i, &deg)| SrbfFrame {
            rotation: if i % 2 == 0 {
                sg::rotation(Vec3::Y, deg)
            } else {
                sg::rotation(Vec3::new(1.0, 2.0, -0.5), deg)
            },
            albedo: [0.8, 0.6, 0.4],
        })
        .collect();
    common::with_gpu(|ctx| {
        let mut setup = ctx.recorder("srbf setup")?;
        let kernel = SrbfKernel::new(&mut setup, &inputs(s))?;
        setup.submit_and_wait()?;
        let names: Vec<&str> = kernel.passes().iter().map(|p| p.name).collect();
        assert_eq!(
            names,
            ["srbf lighting", "srbf project", "srbf sharp", "srbf shade"]
        );
        let compact = s.compact.as_ref().map_or(0, |_| 3);
        assert_eq!(kernel.compact_count(), compact);
        if compact > 0 {
            // Both kinds of compact lobe: the resolved ones spread over four taps.
            let (_, lobes) = inputs(s).split();
            let points = sharp::points(&lobes, sharp::DEFAULT_FIT_WIDTH);
            assert!(
                points.contains(&true) && points.contains(&false),
                "{points:?}"
            );
        }
        let mut done = 0;
        run_frames(ctx, &kernel, &frames, 2, |r| {
            let want = cpu(s, &frames[r.index]);
            // f32 on the GPU: each coefficient sums 48 products, each row 300 terms and each
            // vertex 7 (or 300) terms, of mixed sign; relative to the output's scale the
            // rounding is ~1e-6 per term, so the error bound is 1e-4 of the largest |value|.
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
            assert!(
                r.timings.get("srbf lighting").is_some() && r.timings.get("srbf shade").is_some()
            );
            done += 1;
            Ok(())
        })?;
        assert_eq!(done, frames.len());
        Ok(())
    });
}

#[test]
fn bad_srbf_inputs_and_frames_are_refused() {
    let s = scene(4, 16, 10, 1, 0);
    common::with_gpu(|ctx| {
        let mut rec = ctx.recorder("bad srbf")?;
        let mut short = s.transfer.clone();
        short.weights.pop();
        let e = SrbfKernel::new(&mut rec, &SrbfInputs::new(&s.lobes, &short))
            .err()
            .unwrap();
        assert!(e.to_string().contains("weights"), "{e}");
        let mut stray = s.transfer.clone();
        stray.cluster_of[3] = 1;
        let e = SrbfKernel::new(&mut rec, &SrbfInputs::new(&s.lobes, &stray))
            .err()
            .unwrap();
        assert!(e.to_string().contains("vertex 3"), "{e}");
        // A weight that half precision cannot hold (the GPU streams the weights as f16).
        let mut huge = s.transfer.clone();
        huge.weights[5] = 7.0e4;
        let e = SrbfKernel::new(&mut rec, &SrbfInputs::new(&s.lobes, &huge))
            .err()
            .unwrap();
        assert!(
            e.to_string().contains("weight 5") && e.to_string().contains("half precision"),
            "{e}"
        );
        let mut bad_lobes = s.lobes.clone();
        bad_lobes[2].sharpness = f32::NAN;
        let e = SrbfKernel::new(
            &mut rec,
            &SrbfInputs {
                lobes: &bad_lobes,
                ..inputs(&s)
            },
        )
        .err()
        .unwrap();
        assert!(e.to_string().contains("lobe 2"), "{e}");
        // Compact lobes with a visibility cast for another grid, or for other vertices.
        let c = scene(4, 16, 10, 1, 0).with_compact();
        let cs = c.compact.as_ref().unwrap();
        let wrong_grid = CompactInputs {
            visibility: &cs.vis,
            normals: &cs.normals,
            width: 32,
            height: 16,
            factor: sharp::DEFAULT_FACTOR,
            max_lobes: 4,
            fit_width: sharp::DEFAULT_FIT_WIDTH,
        };
        let e = SrbfKernel::new(
            &mut rec,
            &SrbfInputs::new(&c.lobes, &c.transfer).with_compact(wrong_grid),
        )
        .err()
        .unwrap();
        assert!(e.to_string().contains("32 x 16 grid"), "{e}");
        let e = SrbfKernel::new(
            &mut rec,
            &SrbfInputs::new(&c.lobes, &c.transfer).with_compact(CompactInputs {
                normals: &cs.normals[1..],
                width: 64,
                height: 32,
                ..wrong_grid
            }),
        )
        .err()
        .unwrap();
        assert!(e.to_string().contains("9 normals"), "{e}");
        // A fit width the fit refuses (odd): which compact lobes are points is undefined.
        let e = SrbfKernel::new(
            &mut rec,
            &SrbfInputs::new(&c.lobes, &c.transfer).with_compact(CompactInputs {
                width: 64,
                height: 32,
                fit_width: 127,
                ..wrong_grid
            }),
        )
        .err()
        .unwrap();
        assert!(e.to_string().contains("fit width 127"), "{e}");
        let kernel = SrbfKernel::new(&mut rec, &inputs(&s))?;
        let e = kernel
            .record(
                &mut rec,
                &SrbfFrame {
                    rotation: Mat3::from_diagonal(Vec3::new(1.0, 2.0, 1.0)),
                    albedo: [1.0; 3],
                },
            )
            .unwrap_err();
        assert!(e.to_string().contains("not a rotation"), "{e}");
        let e = kernel
            .record(
                &mut rec,
                &SrbfFrame {
                    rotation: Mat3::IDENTITY,
                    albedo: [1.0, -1.0, 0.0],
                },
            )
            .unwrap_err();
        assert!(e.to_string().contains("albedo"), "{e}");
        rec.submit_and_wait()?;
        Ok(())
    });
}

/// The whole method on real maps and a real mesh against the brute-force ground truth:
/// Testwuson (3205 vertices), 32 lobes, 256 basis functions compressed to 64 clusters x 16
/// components, directions of a 64x32 map, compact lobes shaded from the visibility (the
/// defaults); rotations about +Y and a tilted axis. Blender's forest light (soft) and sunrise
/// (a sun holding 63% of the energy: the case compact lobes are for). The error must stay under
/// the 5% and must not grow with the angle.
#[test]
fn method_against_the_brute_force_ground_truth_on_a_real_map_and_mesh() {
    ground_truth_case(vkshade::kernels::srbf::DEFAULT_ENV, 0.05);
}

/// Off the grid (the tilted rotation) a sun falls between the 64 x 32 directions whose
/// visibility the method holds, while the ground truth casts rays at its exact rotated
/// direction: measured 0.120 here (and 0.06-0.09 at x:60 / z:30 from the CLI, with or without
/// compact lobes: the grid's visibility alone, the "fit" share, is 0.05-0.07 there). The
/// whole pipeline is deterministic (fit, transfer, compression; the GPU matches the CPU to
/// 1e-4), so the bound is that plus a small margin: 0.13 (it was 0.15, which let the error
/// grow by a quarter unnoticed); the 5% holds on the grid.
#[test]
fn a_sun_against_the_brute_force_ground_truth() {
    ground_truth_case(
        "/usr/share/blender/datafiles/studiolights/world/sunrise.exr",
        0.13,
    );
}

/// `off_grid_bound`: the bound for the rotation that does not map the direction grid onto
/// itself.
fn ground_truth_case(env_path: &str, off_grid_bound: f64) {
    use vkshade::app::srbf::RelL2;
    use vkshade::kernels::srbf::diffuse_transfer;
    use vkshade::kernels::srbf::fit::{FitConfig, fit};
    use vkshade::reference::srbf::shade_ground_truth;
    use vkshade::scene::envmap::texel_visibility;
    let env_path = std::path::Path::new(env_path);
    let env = EnvMap::load(env_path).unwrap_or_else(|e| {
        panic!("{e}\nThe Blender studio lights come from `apt-get install blender-data` (tools/setup.sh).")
    });
    let mesh_path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("data/testwuson.glb");
    let character = vkshade::scene::load(&mesh_path)
        .unwrap_or_else(|e| panic!("{e}\nThe test character comes from tools/setup.sh."));
    let mesh = &character.mesh;
    let fitted = fit(
        &env.downsampled(128).unwrap().samples(),
        &FitConfig {
            lobes: 32,
            ..FitConfig::default()
        },
    )
    .unwrap();
    let dir_env = env.downsampled(64).unwrap();
    let vis = texel_visibility(mesh, &dir_env);
    let transfer = diffuse_transfer(&Basis::fibonacci(256), &dir_env, &mesh.normals, &vis).unwrap();
    // The shipped default: 64 clusters x 16 components.
    let cpca = Cpca::compress(&transfer, &CpcaConfig::default()).unwrap();
    let inputs = SrbfInputs::new(&fitted.lobes, &cpca).with_compact(CompactInputs {
        visibility: &vis,
        normals: &mesh.normals,
        width: dir_env.width,
        height: dir_env.height,
        factor: sharp::DEFAULT_FACTOR,
        max_lobes: sharp::DEFAULT_MAX_LOBES,
        fit_width: sharp::DEFAULT_FIT_WIDTH,
    });
    let rotations: Vec<(String, Mat3)> = [0.0f32, 45.0, 90.0, 180.0, 270.0]
        .iter()
        .map(|&d| (format!("y:{d}"), sg::rotation(Vec3::Y, d)))
        .chain([(
            "tilted 60".to_string(),
            sg::rotation(Vec3::new(1.0, 1.0, 0.0), 60.0),
        )])
        .collect();
    common::with_gpu(|ctx| {
        let mut setup = ctx.recorder("srbf setup")?;
        let kernel = SrbfKernel::new(&mut setup, &inputs)?;
        setup.submit_and_wait()?;
        let frames: Vec<SrbfFrame> = rotations
            .iter()
            .map(|(_, r)| SrbfFrame {
                rotation: *r,
                albedo: [1.0; 3],
            })
            .collect();
        let grid_preserving: std::collections::HashMap<usize, &str> = rotations
            .iter()
            .enumerate()
            .filter(|(_, (name, _))| name.starts_with("y:"))
            .map(|(i, (name, _))| (i, name.as_str()))
            .collect();
        let mut errors = Vec::new();
        run_frames(ctx, &kernel, &frames, 2, |r| {
            let frame = &frames[r.index];
            let gpu: Vec<[f64; 3]> = r.output.iter().map(|c| c.map(|x| x as f64)).collect();
            let cpu = inputs.cpu_pipeline(frame)?;
            let truth = shade_ground_truth(&dir_env, frame.rotation, mesh, None, frame.albedo)?;
            if let Some(fast) = grid_preserving.get(&r.index) {
                // About +Y by 45-degree steps: the grid's own visibility gives the same sum.
                let quick =
                    shade_ground_truth(&dir_env, frame.rotation, mesh, Some(&vis), frame.albedo)?;
                let d = RelL2::of(&quick, &truth).all;
                assert!(d < 1e-6, "{fast}: grid-preserving shortcut differs by {d}");
            }
            let (gc, gt) = (RelL2::of(&gpu, &cpu), RelL2::of(&gpu, &truth));
            eprintln!(
                "{}: GPU vs CPU {:.2e}; vs ground truth {:.4} (rgb {:.4} {:.4} {:.4})",
                rotations[r.index].0, gc.all, gt.all, gt.rgb[0], gt.rgb[1], gt.rgb[2]
            );
            assert!(gc.all < 1e-4, "GPU vs CPU of the same pipeline: {gc:?}");
            errors.push(gt.all);
            Ok(())
        })?;
        eprintln!(
            "{}: {} compact lobes; fit relative L2 {:.4}, transfer projection {:.4}, \
             compression {:.4}",
            env_path.display(),
            kernel.compact_count(),
            fitted.rel_l2,
            transfer.projection_rel_l2,
            cpca.rel_l2
        );
        let on_grid: Vec<f64> = (0..errors.len())
            .filter(|i| grid_preserving.contains_key(i))
            .map(|i| errors[i])
            .collect();
        let worst = on_grid.iter().cloned().fold(0f64, f64::max);
        assert!(
            worst < 0.05,
            "relative L2 against the ground truth {errors:?}"
        );
        for (i, e) in errors.iter().enumerate() {
            assert!(
                grid_preserving.contains_key(&i) || *e < off_grid_bound,
                "{}: {e} (bound {off_grid_bound})",
                rotations[i].0
            );
        }
        // Not growing with the angle: every rotation within 1.5x of the unrotated error
        // (plus a floor for quadrature noise); off the grid too where the off-grid bound is
        // the (forest: no sun between the grid's directions).
        let held: Vec<f64> = if off_grid_bound <= 0.05 {
            errors.clone()
        } else {
            on_grid.clone()
        };
        assert!(
            held.iter().all(|e| *e <= 1.5 * errors[0] + 0.005),
            "{errors:?}"
        );
        Ok(())
    });
}
