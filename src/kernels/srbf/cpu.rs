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

    /// [`Self::add_compact`] for the compact lobes `compact` of checked inputs.
    fn add_taps(&self, compact: &[Lobe], frame: &SrbfFrame, out: &mut [[f64; 3]]) -> Result<()> {
        if let (Some(c), false) = (&self.compact, compact.is_empty()) {
            let taps = sharp::taps(compact, frame.rotation, c.width, c.height);
            let direct = sharp::shade(&taps, c.normals, c.visibility)?;
            for (o, d) in out.iter_mut().zip(direct) {
                for ch in 0..3 {
                    o[ch] += (frame.albedo[ch] * d[ch]) as f64;
                }
            }
        }
        Ok(())
    }
}
