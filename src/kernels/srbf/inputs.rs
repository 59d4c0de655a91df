//! What the SRBF kernel is built from and what one frame takes, and their checks (the
//! shaders index with these sizes; the GPU must never read out of bounds or produce NaN).

use super::cpca::Cpca;
use super::pack::{MAX_BASIS, MAX_ROWS, rows_needed};
use super::sharp;
use crate::error::{Error, Result};
use crate::geom::Bvh;
use crate::geom::sg::Lobe;
use crate::geom::visibility::Visibility;
use glam::{Mat3, Vec3};

/// One frame's input: the environment's rotation and the surface albedo.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SrbfFrame {
    /// L_R(w) = L(R^-1 w).
    pub rotation: Mat3,
    pub albedo: [f32; 3],
}

impl SrbfFrame {
    /// Checks that the rotation is one and the albedo finite and >= 0.
    pub fn check(&self) -> Result<()> {
        let r = self.rotation;
        let orthonormal = (r.transpose() * r - Mat3::IDENTITY)
            .to_cols_array()
            .iter()
            .all(|x| x.abs() < 1e-4);
        if !r.is_finite() || !orthonormal || r.determinant() < 0.0 {
            return Err(Error::InvalidArgument(format!(
                "the environment rotation is not a rotation matrix: {r:?}"
            )));
        }
        if self.albedo.iter().any(|a| !a.is_finite() || *a < 0.0) {
            return Err(Error::InvalidArgument(format!(
                "albedo {:?} must be finite and >= 0",
                self.albedo
            )));
        }
        Ok(())
    }
}

/// What the kernel is built from: the lighting lobes and the per-vertex transfer in
/// clustered-PCA form on a basis of spherical Gaussians ([`Cpca::exact`] for the
/// uncompressed transfer), and optionally the visibility that compact lobes are shaded from
/// ([`super::sharp`]).
pub struct SrbfInputs<'a> {
    pub lobes: &'a [Lobe],
    pub transfer: &'a Cpca,
    pub compact: Option<CompactInputs<'a>>,
    /// Shadow rays for the compact lobes at their exact rotated directions; None: the grid
    /// tap ([`super::sharp`]).
    pub rays: Option<SunRays<'a>>,
}

/// What the compact lobes' shadow rays are cast against ([`super::sharp`], "a sun at any
/// rotation"): the vertex positions (the same vertices as the transfer, in the same order),
/// a BVH built once over the static mesh, and the ray origin's offset along the normal
/// (scene units; [`crate::scene::envmap::texel_visibility`] uses 1e-4 of the bounding box's
/// diagonal, [`sun_offset`]).
#[derive(Clone, Copy)]
pub struct SunRays<'a> {
    pub positions: &'a [Vec3],
    pub bvh: &'a Bvh,
    pub offset: f32,
}

/// The ray offset of [`crate::scene::envmap::texel_visibility`] for a mesh with these
/// positions: 1e-4 of its bounding box's diagonal.
pub fn sun_offset(positions: &[Vec3]) -> f32 {
    let lo = positions.iter().fold(Vec3::INFINITY, |a, p| a.min(*p));
    let hi = positions.iter().fold(Vec3::NEG_INFINITY, |a, p| a.max(*p));
    if positions.is_empty() {
        0.0
    } else {
        1e-4 * (hi - lo).length()
    }
}

/// The per-vertex data for shading compact lobes directly: the visibility cast for the
/// texel centres of a `width` x `height` equirectangular grid, the vertex normals, and the
/// sharpness factor and the most lobes to shade directly ([`super::sharp::split`]).
#[derive(Clone, Copy)]
pub struct CompactInputs<'a> {
    pub visibility: &'a Visibility,
    pub normals: &'a [Vec3],
    pub width: u32,
    pub height: u32,
    pub factor: f32,
    pub max_lobes: usize,
    /// Width of the map the lobes were fitted to (its height half that): a lobe the fit
    /// could not resolve is a point source ([`super::sharp::is_point`]).
    pub fit_width: u32,
}

impl<'a> SrbfInputs<'a> {
    pub fn new(lobes: &'a [Lobe], transfer: &'a Cpca) -> Self {
        SrbfInputs {
            lobes,
            transfer,
            compact: None,
            rays: None,
        }
    }

    /// The same, with the compact lobes shadowed by rays at their exact rotated directions
    /// (needs [`Self::with_compact`]).
    pub fn with_rays(mut self, rays: SunRays<'a>) -> Self {
        self.rays = Some(rays);
        self
    }

    /// The same, with compact lobes shaded from `compact`'s visibility.
    pub fn with_compact(mut self, compact: CompactInputs<'a>) -> Self {
        self.compact = Some(compact);
        self
    }

    /// (lobes through the basis, compact lobes).
    pub fn split(&self) -> (Vec<Lobe>, Vec<Lobe>) {
        match &self.compact {
            Some(c) => sharp::split(
                self.lobes,
                self.transfer.basis.sharpness,
                c.factor,
                c.max_lobes,
            ),
            None => (self.lobes.to_vec(), Vec::new()),
        }
    }

    /// For each of `compact` (the second part of [`Self::split`]), whether it is a point
    /// source ([`sharp::is_point`]); all points without compact inputs.
    pub fn compact_points(&self, compact: &[Lobe]) -> Vec<bool> {
        match &self.compact {
            Some(c) => sharp::points(compact, c.fit_width),
            None => vec![true; compact.len()],
        }
    }

    /// Checks the compact-lobe inputs, if any (part of [`Self::check`]).
    pub(super) fn check_compact(&self) -> Result<()> {
        let bad = |what: String| Err(Error::InvalidArgument(format!("SRBF input: {what}")));
        let Some(c) = &self.compact else {
            return Ok(());
        };
        sharp::check_grid(c.visibility, c.width, c.height)?;
        if c.width as u64 * c.height as u64 > 1 << 24 {
            return bad(format!(
                "compact lobes: a {} x {} grid has more texels than a float holds exactly",
                c.width, c.height
            ));
        }
        let vertices = self.transfer.vertices;
        if c.visibility.vertices != vertices || c.normals.len() != vertices {
            return bad(format!(
                "compact lobes: visibility of {} vertices and {} normals for a transfer of \
                 {vertices}",
                c.visibility.vertices,
                c.normals.len(),
            ));
        }
        if let Some(i) = c.normals.iter().position(|n| !n.is_finite()) {
            return bad(format!("normal {i} is not finite"));
        }
        if c.factor.is_nan() || c.factor < 0.0 {
            return bad(format!("sharpness factor {} must be >= 0", c.factor));
        }
        sharp::check_fit_width(c.fit_width)?;
        self.check_rays()
    }

    /// Checks the shadow-ray inputs, if any (part of [`Self::check_compact`]).
    fn check_rays(&self) -> Result<()> {
        let bad = |what: String| Err(Error::InvalidArgument(format!("SRBF input: {what}")));
        let Some(r) = &self.rays else {
            return Ok(());
        };
        let vertices = self.transfer.vertices;
        if r.positions.len() != vertices {
            return bad(format!(
                "sun rays: {} positions for a transfer of {vertices} vertices",
                r.positions.len()
            ));
        }
        if let Some(i) = r.positions.iter().position(|p| !p.is_finite()) {
            return bad(format!("sun rays: position {i} is not finite"));
        }
        if !(r.offset.is_finite() && r.offset >= 0.0) {
            return bad(format!(
                "sun rays: ray offset {} must be finite and >= 0",
                r.offset
            ));
        }
        if r.bvh.is_empty() {
            return bad("sun rays: the BVH holds no triangles".into());
        }
        Ok(())
    }

    /// Checks sizes and values (the shaders index with them; the GPU must never read out of
    /// bounds or produce NaN from bad input).
    pub fn check(&self) -> Result<()> {
        let bad = |what: String| Err(Error::InvalidArgument(format!("SRBF input: {what}")));
        if self.lobes.is_empty() || self.lobes.len() > 65_536 {
            return bad(format!("{} lighting lobes (1..=65536)", self.lobes.len()));
        }
        if let Some(i) = self.lobes.iter().position(|l| !l.is_valid()) {
            return bad(format!("lobe {i} is not a valid SG: {:?}", self.lobes[i]));
        }
        let t = self.transfer;
        t.check()?;
        let k = t.basis.len();
        if k > MAX_BASIS {
            return bad(format!("{k} basis functions (1..={MAX_BASIS})"));
        }
        if self.rays.is_some() && self.compact.is_none() {
            return bad("sun rays need compact lobes (with_compact)".into());
        }
        self.check_compact()?;
        let rows = rows_needed(t.clusters, t.components);
        if rows > MAX_ROWS {
            return bad(format!(
                "{} clusters x {} components need {rows} projected rows; the GPU path holds \
                 {MAX_ROWS} (fewer clusters or components)",
                t.clusters, t.components
            ));
        }
        Ok(())
    }
}
