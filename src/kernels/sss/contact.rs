//! Contact transfer: light that diffuses between separate pieces of a mesh that touch.
//!
//! A head mesh often holds more than one surface: eyeballs sitting in the lids, the inside of
//! the mouth. Texture-space sampling (and any walk over the surface) only reaches the piece
//! the receiver lies on, while the diffusion integral B(xo) = sum Rd(|xj - xo|) E_j A_j runs
//! over every surface point within reach in 3D. Where pieces touch, that part is large: on
//! the BCN_Epileptic head, a shaded lid texel next to the lit eyeball gets nearly all of its
//! light from it (`vkshade sss --reference`: `contact_max_share`).
//!
//! For each covered texel this gathers the texels of *other* connected pieces within the
//! sampling radius (a uniform grid over their positions) and keeps an explicit sum over them:
//! all of them when there are at most [`MAX_ENTRIES`], otherwise [`MAX_ENTRIES`] picked by
//! systematic sampling (offset hashed per receiver) of q_j = sum_c Rd_c(d_j) A_j / K_c (the channels balanced by their
//! own totals), each weighted by its count / (MAX_ENTRIES q_j / sum q). An entry holds the
//! source texel and its per-channel factor f_c, so that the contact term is
//! sum_entries f_c E_c(source): it follows the frame's irradiance exactly and the geometry it
//! was built for (rebuilt with the texture-space geometry, per frame for a skinned mesh).
//!
//! Pieces are the connected components of the mesh with vertices welded by position (so a UV
//! seam does not split a piece). With several skin regions ([`Regions`]) each receiver's sum
//! uses its own region's profile and radius (the exit point's, as the diffusion does).

use super::{Profile, Regions};
use crate::scene::texspace::{COVERED, Dsu, TexGeometry};
use glam::Vec3;
use rayon::prelude::*;
use std::collections::HashMap;

/// Entries kept per receiver at most.
pub const MAX_ENTRIES: usize = 16;

/// The contact sums of a texture-space geometry.
#[derive(Clone, Debug, Default)]
pub struct Contact {
    /// Per texel: (first entry, entry count).
    pub range: Vec<[u32; 2]>,
    /// Source texel index and its factor per channel.
    pub entries: Vec<(u32, [f32; 3])>,
    /// Connected pieces of the mesh.
    pub pieces: usize,
    /// Covered texels with at least one entry.
    pub receivers: usize,
}

/// The connected piece of each triangle, with vertices welded by position; and the count.
pub fn pieces(geo: &TexGeometry) -> (Vec<u32>, usize) {
    let (weld, ids) = super::walk::weld(&geo.positions);
    let mut sets = Dsu::new(ids);
    for t in &geo.triangles {
        sets.union(weld[t[0] as usize] as usize, weld[t[1] as usize] as usize);
        sets.union(weld[t[0] as usize] as usize, weld[t[2] as usize] as usize);
    }
    let mut label: HashMap<u32, u32> = HashMap::new();
    let of_tri: Vec<u32> = geo
        .triangles
        .iter()
        .map(|t| {
            let root = sets.find(weld[t[0] as usize] as usize);
            let next = label.len() as u32;
            *label.entry(root as u32).or_insert(next)
        })
        .collect();
    (of_tri, label.len())
}

/// Source texel j's factor per channel: [`Profile::rd_over_texel`] from receiver `po`, 0
/// beyond the channel's sampling radius.
fn source_factor(
    geo: &TexGeometry,
    profile: &Profile,
    radius: &[f32; 3],
    po: Vec3,
    j: usize,
    area: f32,
) -> [f32; 3] {
    let nf = geo.size as f64;
    let v = |a: &[f32; 4]| Vec3::from_slice(&a[..3]).as_dvec3();
    let pj = v(&geo.pos[j]);
    let f = profile.rd_over_texel(
        po.as_dvec3(),
        pj,
        v(&geo.dpdu[j]) / nf,
        v(&geo.dpdv[j]) / nf,
        area as f64,
    );
    let d = (pj - po.as_dvec3()).length();
    [0, 1, 2].map(|c| {
        if d <= radius[c] as f64 {
            f[c] as f32
        } else {
            0.0
        }
    })
}

impl Contact {
    /// The contact sums for `geo` and its regions' profiles (none when the mesh is one
    /// piece).
    pub fn build(geo: &TexGeometry, regions: &Regions) -> Contact {
        Contact::build_with(geo, regions, MAX_ENTRIES)
    }

    /// [`Contact::build`] keeping at most `max_entries` (1..=31) per receiver.
    pub fn build_with(geo: &TexGeometry, regions: &Regions, max_entries: usize) -> Contact {
        let max_entries = max_entries.clamp(1, 31);
        let n = geo.texels();
        let (piece, count) = pieces(geo);
        let mut out = Contact {
            range: vec![[0, 0]; n],
            pieces: count,
            ..Default::default()
        };
        if count < 2 {
            return out;
        }
        // The grid's cell is the largest radius of any region; each receiver then keeps the
        // sources within its own region's radii.
        let rmax = regions.max_radius() as f32;
        let covered: Vec<usize> = (0..n).filter(|&i| geo.pos[i][3] == COVERED).collect();
        let pos = |i: usize| Vec3::from_slice(&geo.pos[i][..3]);
        let piece_of = |i: usize| piece[geo.texel_tri[i][0] as usize];
        let key = |p: Vec3| {
            let q = (p / rmax).floor();
            (q.x as i32, q.y as i32, q.z as i32)
        };
        // One grid per piece: a receiver visits the other pieces' cells only.
        let mut grid: HashMap<(u32, i32, i32, i32), Vec<u32>> = HashMap::new();
        for &i in &covered {
            let (x, y, z) = key(pos(i));
            grid.entry((piece_of(i), x, y, z))
                .or_default()
                .push(i as u32);
        }
        let lists: Vec<Vec<(u32, [f32; 3])>> = covered
            .par_iter()
            .map(|&o| {
                let profile = regions.of_triangle_profile(geo.texel_tri[o][0] as usize);
                let radius = profile.radius.map(|r| r as f32);
                let rmax = radius.iter().cloned().fold(0.0, f32::max);
                let k = profile.k.map(|k| k as f32);
                let po = pos(o);
                let me = piece_of(o);
                let (kx, ky, kz) = key(po);
                // (source, q, per-channel Rd A)
                let mut cand: Vec<(u32, f32, [f32; 3])> = Vec::new();
                let cells = (0..count as u32).filter(|&p| p != me).flat_map(|p| {
                    (0..27).map(move |c| (p, kx + c % 3 - 1, ky + c / 3 % 3 - 1, kz + c / 9 - 1))
                });
                for cell in cells {
                    let Some(list) = grid.get(&cell) else {
                        continue;
                    };
                    for &j in list {
                        let j = j as usize;
                        let d = (pos(j) - po).length();
                        if d > rmax {
                            continue;
                        }
                        let a = geo.nrm[j][3];
                        let f = source_factor(geo, profile, &radius, po, j, a);
                        let q = (0..3).map(|c| f[c] / k[c]).sum::<f32>();
                        if q > 0.0 && q.is_finite() {
                            cand.push((j as u32, q, f));
                        }
                    }
                }
                if cand.len() <= max_entries {
                    return cand.into_iter().map(|(j, _, f)| (j, f)).collect();
                }
                cand.sort_by_key(|c| c.0);
                let total: f64 = cand.iter().map(|c| c.1 as f64).sum();
                let step = total / max_entries as f64;
                // Systematic sampling: picks at (m + u) step along the cumulative q, with u
                // hashed from the receiver (a random offset makes each pick's weight unbiased;
                // neighbours, with nearly the same lists, then err independently).
                let u = (super::cpu::pcg(o as u32 ^ 0x9e37_79b9) >> 8) as f64 / 16_777_216.0;
                let mut picked: Vec<(u32, [f32; 3])> = Vec::new();
                let mut acc = 0.0f64;
                let mut m = 0usize;
                for &(j, q, f) in &cand {
                    let lo = acc;
                    acc += q as f64;
                    let mut hits = 0u32;
                    while m < max_entries && (m as f64 + u) * step < acc {
                        if (m as f64 + u) * step >= lo {
                            hits += 1;
                        }
                        m += 1;
                    }
                    if hits > 0 {
                        let w = hits as f64 * step / q as f64;
                        picked.push((j, f.map(|x| (x as f64 * w) as f32)));
                    }
                }
                picked
            })
            .collect();
        for (&o, list) in covered.iter().zip(lists) {
            if list.is_empty() {
                continue;
            }
            out.range[o] = [out.entries.len() as u32, list.len() as u32];
            out.receivers += 1;
            out.entries.extend(list);
        }
        out
    }

    /// The contact term per texel (rgb) for irradiance `e`.
    pub fn apply(&self, e: &[[f32; 4]]) -> Vec<[f32; 3]> {
        self.range
            .iter()
            .map(|&[first, count]| {
                let mut s = [0f32; 3];
                for &(j, f) in &self.entries[first as usize..(first + count) as usize] {
                    for c in 0..3 {
                        s[c] += f[c] * e[j as usize][c];
                    }
                }
                s
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::kernels::sss::{Material, ProfileKind};
    use crate::reference::sss::{Sources, brute_force_where};
    use crate::scene::Mesh;
    use crate::scene::mesh::MeshData;
    use glam::DVec3;

    /// Two 10 x 10 mm squares facing each other `gap` mm apart (separate pieces), at UV
    /// [0.05, 0.45] and [0.55, 0.95] in u.
    fn facing_squares(gap: f32) -> TexGeometry {
        let mut data = MeshData {
            name: "facing squares".into(),
            ..Default::default()
        };
        let mut uvs = Vec::new();
        for (z, u0) in [(0.0, 0.05), (gap, 0.55)] {
            for (x, y) in [(0.0, 0.0), (10.0, 0.0), (10.0, 10.0), (0.0, 10.0)] {
                data.positions.push([x, y, z]);
                uvs.push([u0 + 0.04 * x, 0.3 + 0.04 * y]);
            }
        }
        data.triangles = vec![[0, 1, 2], [0, 2, 3], [4, 6, 5], [4, 7, 6]];
        data.uvs = Some(uvs);
        let mesh = Mesh::from_data(data, std::path::Path::new("<facing squares>")).unwrap();
        TexGeometry::build(&mesh, 64, 1.0).unwrap()
    }

    #[test]
    fn light_from_a_facing_piece_matches_the_brute_force() {
        let geo = facing_squares(1.0);
        let profile = Profile::new(ProfileKind::Dipole, Material::SKIN1, 0.995).unwrap();
        assert_eq!(pieces(&geo).1, 2);
        let contact = Contact::build(&geo, &(&profile).into());
        // Light on the upper square only.
        let e: Vec<[f32; 4]> = geo
            .pos
            .iter()
            .map(|p| if p[2] > 0.5 { [1.0; 4] } else { [0.0; 4] })
            .collect();
        let term = contact.apply(&e);
        let covered: Vec<usize> = (0..geo.texels())
            .filter(|&i| geo.pos[i][3] == COVERED && geo.pos[i][2] < 0.5)
            .collect();
        assert!(
            covered
                .iter()
                .all(|&i| contact.range[i][1] as usize == MAX_ENTRIES)
        );
        let sources = Sources::from_texels(&geo, &e);
        let receivers: Vec<DVec3> = covered
            .iter()
            .map(|&i| Vec3::from_slice(&geo.pos[i][..3]).as_dvec3())
            .collect();
        let truth = brute_force_where(&sources, &receivers, &profile, |_, j| {
            sources.pos[j].z > 0.5
        });
        let est: Vec<[f64; 3]> = covered
            .iter()
            .map(|&i| [0, 1, 2].map(|c| term[i][c] as f64))
            .collect();
        let w: Vec<f64> = covered.iter().map(|&i| geo.nrm[i][3] as f64).collect();
        let err = crate::reference::sss::ChannelError::of(&est, &truth, &w);
        eprintln!("contact vs brute force: {err:?}");
        // 16 of the hundreds of sources within reach, picked by systematic sampling of the
        // channels' mean Rd A with an offset hashed per receiver: a per-texel error where a
        // channel's profile differs from that mean (measured: rel RMSE 0.045 / 0.031 / 0.051,
        // energy 1.001 / 0.997 / 0.986, worst texel 0.18 / 0.13 / 0.18; the sampling radius
        // also drops the truth's last 0.5%). Bounds with margin:
        for c in 0..3 {
            assert!(err.rel_rmse[c] < 0.07, "channel {c}: {err:?}");
            assert!(
                (err.energy_ratio[c] - 1.0).abs() < 0.02,
                "channel {c}: {err:?}"
            );
        }
    }

    #[test]
    fn one_piece_has_no_contact() {
        let geo = TexGeometry::build(
            &crate::scene::texspace::plane_mesh(20.0, 20.0, 3).unwrap(),
            32,
            1.0,
        )
        .unwrap();
        let profile = Profile::new(ProfileKind::Burley, Material::SKIN1, 0.995).unwrap();
        let contact = Contact::build(&geo, &(&profile).into());
        assert_eq!(
            (contact.pieces, contact.receivers, contact.entries.len()),
            (1, 0, 0)
        );
    }
}
