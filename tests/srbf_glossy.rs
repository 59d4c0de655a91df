//! Glossy SRBF transfer: the GPU against its CPU twin under validation, and the method against
//! the brute-force glossy truth on a real mesh and map.

mod common;

use glam::{Mat3, Vec3};
use vkshade::geom::Rng;
use vkshade::geom::sg::{self, Lobe};
use vkshade::kernels::srbf::brdf::Brdf;
use vkshade::kernels::srbf::glossy::{GlossyTransfer, ViewGrid};
use vkshade::kernels::srbf::glossy_gpu::{GlossyFrame, GlossyInputs, GlossyKernel};
use vkshade::kernels::srbf::transfer::{Basis, Transfer};
use vkshade::kernels::{Kernel, run_frames};

/// Random lobes, a random glossy transfer (K = 96 basis functions, a 5 x 5 view grid),
/// random points in a box and random unit normals.
struct Scene {
    lobes: Vec<Lobe>,
    transfer: GlossyTransfer,
    positions: Vec<Vec3>,
    normals: Vec<Vec3>,
}

fn scene(vertices: usize) -> Scene {
    let mut rng = Rng::new(19);
    let lobes = (0..40)
        .map(|_| Lobe {
            axis: vkshade::geom::uniform_sphere(rng.f32(), rng.f32()).to_array(),
            sharpness: 1.0 + 60.0 * rng.f32() * rng.f32(),
            amplitude: [rng.f32() * 3.0, rng.f32() * 2.0, rng.f32()],
        })
        .collect();
    let (k, grid) = (96, ViewGrid { n: 5 });
    let rows = vertices * grid.views();
    let transfer = GlossyTransfer {
        rows: Transfer {
            basis: Basis::fibonacci(k),
            vertices: rows,
            coeffs: (0..rows * k).map(|_| rng.f32() * 0.1 - 0.03).collect(),
            projection_rel_l2: 0.0,
        },
        vertices,
        grid,
        brdf: Brdf::Phong {
            exponent: 8.0,
            diffuse: 0.4,
            specular: 0.6,
        },
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
    }
}

#[test]
fn glossy_gpu_matches_its_cpu_twin() {
    let s = scene(1000);
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
            // f32 on the GPU: each coefficient sums 40 products and each vertex 4 x 96 terms
            // of mixed sign; the twin sums the same f32 inputs in f64. ~1e-6 per term of the
            // output's scale, so 1e-4 of the largest |value|. The tap weights are computed in
            // f32 on both sides from the same formulas; a vertex whose view falls exactly on a
            // cell edge could pick the neighbouring cell, which changes nothing (weight 0).
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
    let s = scene(10);
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
    grid.grid = ViewGrid { n: 1 };
    assert!(grid.check().unwrap_err().to_string().contains("1 x 1"));
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
