//! The CPU twin of the SRBF kernel's passes for one frame: the lighting's coefficients in
//! the transfer basis, the clustered-PCA shading and the compact lobes shaded from the
//! visibility (f32 inputs, f64 results).

use super::inputs::{SrbfFrame, SrbfInputs};
use super::{sharp, transfer};
use crate::error::Result;
use crate::geom::sg::Lobe;

impl SrbfInputs<'_> {
    /// The CPU twin of the whole GPU pipeline for one frame (f32 inputs, f64 results).
    pub fn cpu_pipeline(&self, frame: &SrbfFrame) -> Result<Vec<[f64; 3]>> {
        self.check()?;
        let (smooth, compact) = self.split();
        let coeffs = transfer::lighting_coefficients(&smooth, frame.rotation, &self.transfer.basis);
        let mut out: Vec<[f64; 3]> = self
            .transfer
            .shade(&coeffs, frame.albedo)?
            .iter()
            .map(|c| c.map(|x| x as f64))
            .collect();
        self.add_taps(&compact, frame, &mut out)?;
        Ok(out)
    }

    /// Adds the compact lobes' radiance (albedo included) to `out` (one entry per vertex);
    /// nothing when there are none.
    pub fn add_compact(&self, frame: &SrbfFrame, out: &mut [[f64; 3]]) -> Result<()> {
        self.check_compact()?;
        let (_, compact) = self.split();
        self.add_taps(&compact, frame, out)
    }

    /// [`Self::add_compact`] for the compact lobes `compact` of checked inputs: the grid
    /// tap, or with [`SrbfInputs::rays`] shadow rays at the exact rotated axes.
    fn add_taps(&self, compact: &[Lobe], frame: &SrbfFrame, out: &mut [[f64; 3]]) -> Result<()> {
        if let (Some(c), false) = (&self.compact, compact.is_empty()) {
            let direct = match &self.rays {
                Some(r) => {
                    let taps = sharp::ray_taps(compact, frame.rotation);
                    let bits = sharp::ray_bits(&taps, r.positions, c.normals, r.bvh, r.offset);
                    sharp::shade_bits(&taps, c.normals, &bits)?
                }
                None => {
                    let points = self.compact_points(compact);
                    let taps = sharp::taps(compact, &points, frame.rotation, c.width, c.height);
                    sharp::shade(&taps, c.normals, c.visibility)?
                }
            };
            for (o, d) in out.iter_mut().zip(direct) {
                for ch in 0..3 {
                    o[ch] += (frame.albedo[ch] * d[ch]) as f64;
                }
            }
        }
        Ok(())
    }

    /// The CPU twin of the shadow-ray bits of pass `srbf sharp` for `frame` (bit j of vertex
    /// v: compact lobe j seen from v, [`sharp::ray_bits`]); None without shadow rays.
    pub fn sun_bits(&self, frame: &SrbfFrame) -> Result<Option<Vec<u32>>> {
        self.check()?;
        let (Some(c), Some(r)) = (&self.compact, &self.rays) else {
            return Ok(None);
        };
        let (_, compact) = self.split();
        let taps = sharp::ray_taps(&compact, frame.rotation);
        Ok(Some(sharp::ray_bits(
            &taps,
            r.positions,
            c.normals,
            r.bvh,
            r.offset,
        )))
    }
}
