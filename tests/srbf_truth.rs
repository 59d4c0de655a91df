//! The SRBF brute-force truth at the map's own resolution (`srbf shade --reference
//! --reference-width full`): exact on analytic cases (a constant map on an unoccluded plane,
//! a one-texel sun at rotations off the grid, diffuse and glossy), and the direction map's
//! coarser truth moving a sun out of a shadow that the full one keeps. CPU only (f64).

use glam::{DVec3, Mat3, Vec3};
use std::f64::consts::PI;
use vkshade::geom::brdf::Brdf;
use vkshade::geom::sg;
use vkshade::reference::srbf::{ReferenceWidth, shade_glossy_truth, shade_ground_truth};
use vkshade::scene::envmap::EnvMap;
use vkshade::scene::{Mesh, MeshData};

/// Receiver points (vertices used by no triangle, normal +Y) at `receivers`, plus an
/// occluding square of half-size `half` centred at `centre`, facing `facing`.
fn scene(receivers: &[Vec3], centre: Vec3, facing: Vec3, half: f32) -> Mesh {
    let facing = facing.normalize();
    let a = facing.any_orthonormal_vector();
    let b = facing.cross(a);
    let mut d = MeshData {
        name: "receivers and a square".into(),
        ..Default::default()
    };
    let mut normals = Vec::new();
    for p in receivers {
        d.positions.push(p.to_array());
        normals.push([0.0, 1.0, 0.0]);
    }
    let base = receivers.len() as u32;
    for (sa, sb) in [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)] {
        d.positions
            .push((centre + half * (sa * a + sb * b)).to_array());
        normals.push(facing.to_array());
    }
    d.normals = Some(normals);
    d.triangles = vec![[base, base + 1, base + 2], [base, base + 2, base + 3]];
    Mesh::from_data(d, std::path::Path::new("test scene")).unwrap()
}

/// A W x W/2 map, black but for texel (x, y) = `l`.
fn sun_map(w: u32, x: u32, y: u32, l: [f32; 3]) -> EnvMap {
    let mut t = vec![[0.0f32; 3]; (w * w / 2) as usize];
    t[(y * w + x) as usize] = l;
    EnvMap::from_texels(w, w / 2, t, "one-texel sun").unwrap()
}

/// A constant map L on receivers nothing occludes (the square is far below them): the
/// truth is albedo L (the cosine integral is pi) up to the midpoint rule's error, which for
/// n = +Y at 256 x 128 is 7.5e-5 relative (unit test `cosine_quadrature_bound_at_64x32` in
/// reference::srbf holds it at 8e-5); rotations about +Y keep every texel's height, so the
/// bound holds off the grid too (40 degrees is not a multiple of 360 / 256).
#[test]
fn full_truth_of_a_constant_map_is_albedo_times_radiance() {
    let receivers = [Vec3::ZERO, Vec3::new(3.0, 0.0, -2.0)];
    let mesh = scene(&receivers, Vec3::new(0.0, -50.0, 0.0), Vec3::Y, 0.5);
    let l = [1.0f32, 2.0, 0.5];
    let env = EnvMap::from_texels(256, 128, vec![l; 256 * 128], "constant").unwrap();
    let albedo = [0.8f32, 0.5, 1.0];
    for rotation in [Mat3::IDENTITY, sg::rotation(Vec3::Y, 40.0)] {
        let b = shade_ground_truth(&env, rotation, &mesh, None, albedo).unwrap();
        for (i, _) in receivers.iter().enumerate() {
            for c in 0..3 {
                let want = albedo[c] as f64 * l[c] as f64;
                let rel = (b[i][c] - want).abs() / want;
                assert!(
                    rel < 8e-5,
                    "receiver {i} channel {c}: {} vs {want}",
                    b[i][c]
                );
            }
        }
    }
}

/// One texel lit: the full truth is that texel's term alone, exactly: albedo / pi x L x
/// dOmega x cos(n, R w) (diffuse) and albedo x L x dOmega x rho cos (Phong), at rotations
/// about any axis (the texel keeps its energy; nothing is resampled). Only f64 rounding
/// separates the two sides (1e-12).
#[test]
fn full_truth_of_a_one_texel_sun_is_the_exact_cosine() {
    let receivers = [Vec3::ZERO, Vec3::new(1.0, 0.0, 1.0)];
    let mesh = scene(&receivers, Vec3::new(0.0, -50.0, 0.0), Vec3::Y, 0.5);
    let (w, x, y) = (256u32, 80u32, 32u32);
    let l = [10.0f32, 20.0, 40.0];
    let env = sun_map(w, x, y, l);
    let (dir, d_omega) = (env.direction(x, y), env.solid_angle(y));
    let albedo = [1.0f32, 0.5, 0.25];
    let camera = Vec3::new(2.0, 3.0, 4.0);
    let phong = Brdf::Phong {
        exponent: 16.0,
        diffuse: 0.3,
        specular: 0.7,
    };
    for rotation in [
        sg::rotation(Vec3::Y, 40.0),
        sg::rotation(Vec3::X, 25.0),
        sg::rotation(Vec3::new(1.0, 2.0, 0.5), 33.0),
    ] {
        let w_r = (rotation * dir).normalize().as_dvec3();
        let cos = w_r.y.max(0.0);
        assert!(cos > 0.3, "the sun stays above the receivers' horizon");
        let diffuse = shade_ground_truth(&env, rotation, &mesh, None, albedo).unwrap();
        let glossy = shade_glossy_truth(
            &env,
            rotation,
            &mesh,
            &receivers,
            &[Vec3::Y; 2],
            &phong,
            camera,
            albedo,
        )
        .unwrap();
        for (i, p) in receivers.iter().enumerate() {
            let o = Brdf::view_direction(DVec3::Y, p.as_dvec3(), camera.as_dvec3());
            for c in 0..3 {
                let e = l[c] as f64 * d_omega * albedo[c] as f64;
                let want_d = e / PI * cos;
                let want_g = e * phong.cosine_weighted(DVec3::Y, w_r, o);
                assert!(
                    (diffuse[i][c] - want_d).abs() <= 1e-12 * want_d,
                    "diffuse {i} {c}: {} vs {want_d}",
                    diffuse[i][c]
                );
                assert!(
                    want_g > 0.0 && (glossy[i][c] - want_g).abs() <= 1e-12 * want_g,
                    "glossy {i} {c}: {} vs {want_g}",
                    glossy[i][c]
                );
            }
        }
    }
}

/// The fit-width (direction-map) truth blurs a sun; the full one does not. A one-texel sun
/// at 256 x 128 sits in the corner of its 4 x 4 block of the 64 x 32 direction map, whose
/// centre is ~2.1 degrees away in each axis; a square subtending +-0.5 degrees around the
/// sun's own direction, 10 units above receiver P, shadows P from the sun. The full truth
/// at P is 0 (the only lit texel is blocked); the 64 x 32 truth moves the sun's energy to
/// the block's centre direction, which misses the square, so P is lit at the unoccluded
/// value (the energy is kept: within 1e-5, f32 texel rounding). An unshadowed receiver Q
/// gets the exact cosine from the full truth and the cosine of the moved direction from the
/// coarse one (they differ by more than 1%).
#[test]
fn direction_map_truth_blurs_a_sun_the_full_truth_does_not() {
    let (w, x, y) = (256u32, 80u32, 32u32);
    let l = [0.0f32, 0.0, 100.0];
    let env = sun_map(w, x, y, l);
    let sun = env.direction(x, y);
    let p = Vec3::ZERO;
    let q = Vec3::new(30.0, 0.0, 30.0);
    let mesh = scene(
        &[p, q],
        p + 10.0 * sun,
        -sun,
        10.0 * 0.5f32.to_radians().tan(),
    );
    let albedo = [1.0f32; 3];
    let full = shade_ground_truth(&env, Mat3::IDENTITY, &mesh, None, albedo).unwrap();
    let coarse_env = ReferenceWidth::Width(64).map(&env, 128).unwrap().unwrap();
    assert_eq!((coarse_env.width, coarse_env.height), (64, 32));
    let coarse = shade_ground_truth(&coarse_env, Mat3::IDENTITY, &mesh, None, albedo).unwrap();
    let energy = l[2] as f64 * env.solid_angle(y);
    let exact_q = energy / PI * sun.as_dvec3().y;
    let centre = coarse_env.direction(x / 4, y / 4).as_dvec3();
    let moved = energy / PI * centre.y;
    assert!(
        sun.as_dvec3().angle_between(centre).to_degrees() > 2.0,
        "the block's centre is more than 2 degrees from the sun"
    );
    // P: shadowed in the full truth, lit in the coarse one.
    assert_eq!(full[0][2], 0.0, "the full truth keeps P in the shadow");
    assert!(
        (coarse[0][2] - moved).abs() <= 1e-5 * moved,
        "the coarse truth lights P: {} vs {moved}",
        coarse[0][2]
    );
    // Q: exact cosine vs the moved direction's cosine.
    assert!((full[1][2] - exact_q).abs() <= 1e-12 * exact_q);
    assert!((coarse[1][2] - moved).abs() <= 1e-5 * moved);
    assert!(
        (moved - exact_q).abs() > 0.01 * exact_q,
        "the coarse sun's cosine differs: {moved} vs {exact_q}"
    );
}

/// `--reference-width`: full is the map itself, directions (or the direction width) is
/// no second map, a width that does not divide the map's is refused with a message naming
/// the map.
#[test]
fn reference_width_parses_and_checks() {
    let env = sun_map(256, 0, 0, [1.0; 3]);
    assert_eq!("full".parse::<ReferenceWidth>(), Ok(ReferenceWidth::Full));
    assert_eq!(
        "directions".parse::<ReferenceWidth>(),
        Ok(ReferenceWidth::Directions)
    );
    assert_eq!(
        "128".parse::<ReferenceWidth>(),
        Ok(ReferenceWidth::Width(128))
    );
    assert!("huge".parse::<ReferenceWidth>().is_err());
    assert_eq!(
        ReferenceWidth::Full.map(&env, 64).unwrap().unwrap().width,
        256
    );
    assert!(ReferenceWidth::Directions.map(&env, 64).unwrap().is_none());
    assert!(ReferenceWidth::Width(64).map(&env, 64).unwrap().is_none());
    let e = ReferenceWidth::Width(96)
        .map(&env, 64)
        .unwrap_err()
        .to_string();
    assert!(e.contains("one-texel sun") && e.contains("96"), "{e}");
    let e = ReferenceWidth::Width(512)
        .map(&env, 64)
        .unwrap_err()
        .to_string();
    assert!(e.contains("512"), "{e}");
}
