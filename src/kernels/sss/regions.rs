//! Multi-region skin: a diffusion profile per region of the mesh (lips, cheeks, ears, hands
//! with their own scattering), as the texture-space methods do it (d'Eon and Luebke 2007,
//! Jimenez et al. 2009): each texel diffuses with the profile of the region it lies in, the
//! exit point's. B(xo) = int E(xi) Rd_{region(xo)}(|xi - xo|) dA(xi): light entering in one
//! region and leaving in another takes the profile where it leaves, so a region's texels far
//! from its border (beyond the profile's sampling radius) see exactly their own profile, and
//! a uniformly lit region gives E R_tot of its own profile right up to its border.
//!
//! A region is a set of triangles ([`Regions::triangle_regions`]); a vertex belongs to the
//! lowest region of the triangles around it (the transmission through thin parts is computed
//! per vertex with that region's profile). Every region shares one [`ProfileKind`] (the
//! transmission pass evaluates one kind of tail).

use super::profile::{Profile, ProfileKind};
use crate::error::{Error, Result};

/// The most regions a kernel takes (the shaders' MAX_REGIONS).
pub const MAX_REGIONS: usize = 8;

/// The profiles of a mesh's regions and which region each triangle is in.
#[derive(Clone, Debug)]
pub struct Regions {
    profiles: Vec<Profile>,
    /// Per triangle its region; empty: every triangle in region 0.
    triangle: Vec<u8>,
}

impl From<&Profile> for Regions {
    /// One profile for the whole mesh.
    fn from(p: &Profile) -> Regions {
        Regions::single(p.clone())
    }
}

impl From<Profile> for Regions {
    fn from(p: Profile) -> Regions {
        Regions::single(p)
    }
}

impl From<&Regions> for Regions {
    fn from(r: &Regions) -> Regions {
        r.clone()
    }
}

impl Regions {
    /// One profile for the whole mesh.
    pub fn single(profile: Profile) -> Regions {
        Regions {
            profiles: vec![profile],
            triangle: Vec::new(),
        }
    }

    /// `profiles` (1..=[`MAX_REGIONS`], one kind) and each triangle's region (an index into
    /// them).
    pub fn new(profiles: Vec<Profile>, triangle: Vec<u8>) -> Result<Regions> {
        if profiles.is_empty() || profiles.len() > MAX_REGIONS {
            return Err(Error::InvalidArgument(format!(
                "{} skin regions; a kernel takes 1..={MAX_REGIONS} profiles",
                profiles.len()
            )));
        }
        let kind = profiles[0].kind;
        if let Some(p) = profiles.iter().find(|p| p.kind != kind) {
            return Err(Error::InvalidArgument(format!(
                "skin regions mix the {kind:?} and {:?} profiles; every region takes the same kind",
                p.kind
            )));
        }
        if let Some((t, r)) = triangle
            .iter()
            .enumerate()
            .find(|(_, r)| **r as usize >= profiles.len())
        {
            return Err(Error::InvalidArgument(format!(
                "triangle {t} is in skin region {r}, but there are {} profiles",
                profiles.len()
            )));
        }
        Ok(Regions { profiles, triangle })
    }

    /// The regions' profiles, by region.
    pub fn profiles(&self) -> &[Profile] {
        &self.profiles
    }

    /// Region `r`'s profile (region 0's when out of range).
    pub fn profile(&self, r: usize) -> &Profile {
        self.profiles.get(r).unwrap_or(&self.profiles[0])
    }

    /// The number of regions (profiles).
    pub fn len(&self) -> usize {
        self.profiles.len()
    }

    /// Never: a [`Regions`] has at least one profile.
    pub fn is_empty(&self) -> bool {
        self.profiles.is_empty()
    }

    /// The profiles' kind.
    pub fn kind(&self) -> ProfileKind {
        self.profiles[0].kind
    }

    /// Per triangle its region (empty: all in region 0).
    pub fn triangle_regions(&self) -> &[u8] {
        &self.triangle
    }

    /// Triangle `t`'s region.
    pub fn of_triangle(&self, t: usize) -> usize {
        self.triangle.get(t).map_or(0, |&r| r as usize)
    }

    /// The profile of the region triangle `t` is in.
    pub fn of_triangle_profile(&self, t: usize) -> &Profile {
        self.profile(self.of_triangle(t))
    }

    /// Checks that the regions fit a mesh of `triangles` triangles.
    pub fn check_mesh(&self, triangles: usize) -> Result<()> {
        if !self.triangle.is_empty() && self.triangle.len() != triangles {
            return Err(Error::InvalidArgument(format!(
                "skin regions for {} triangles, but the mesh has {triangles}",
                self.triangle.len()
            )));
        }
        Ok(())
    }

    /// Per vertex its region: the lowest region of the triangles that use it (0 for a
    /// vertex no triangle uses).
    pub fn of_vertices(&self, triangles: &[[u32; 3]], vertices: usize) -> Vec<u8> {
        if self.triangle.is_empty() {
            return vec![0; vertices];
        }
        let mut out = vec![u8::MAX; vertices];
        for (t, tri) in triangles.iter().enumerate() {
            let r = self.of_triangle(t) as u8;
            for &v in tri {
                if let Some(o) = out.get_mut(v as usize) {
                    *o = (*o).min(r);
                }
            }
        }
        out.iter_mut().for_each(|o| {
            if *o == u8::MAX {
                *o = 0
            }
        });
        out
    }

    /// The largest sampling radius over every region's profile (mm).
    pub fn max_radius(&self) -> f64 {
        self.profiles
            .iter()
            .map(Profile::max_radius)
            .fold(0.0, f64::max)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::kernels::sss::profile::{DEFAULT_ENERGY, Material};

    fn p(kind: ProfileKind, m: Material) -> Profile {
        Profile::new(kind, m, DEFAULT_ENERGY).unwrap()
    }

    #[test]
    fn a_vertex_takes_the_lowest_region_around_it() {
        let skin1 = p(ProfileKind::Dipole, Material::SKIN1);
        let skin2 = p(ProfileKind::Dipole, Material::SKIN2);
        // Two triangles sharing the edge 1-2: region 1 and region 0; vertex 4 unused.
        let r = Regions::new(vec![skin1, skin2], vec![1, 0]).unwrap();
        let v = r.of_vertices(&[[0, 1, 2], [1, 3, 2]], 5);
        assert_eq!(v, vec![1, 0, 0, 0, 0]);
        assert_eq!(r.of_triangle(0), 1);
        assert_eq!(r.of_triangle_profile(0).material.name, "skin2");
        assert!(r.max_radius() >= r.profile(0).max_radius());
        assert!(r.max_radius() >= r.profile(1).max_radius());
        assert!(r.check_mesh(2).is_ok());
        let e = r.check_mesh(3).unwrap_err().to_string();
        assert!(e.contains("for 2 triangles") && e.contains("has 3"), "{e}");
    }

    #[test]
    fn bad_regions_are_refused_with_the_reason() {
        let skin1 = p(ProfileKind::Dipole, Material::SKIN1);
        let e = Regions::new(vec![], vec![]).unwrap_err().to_string();
        assert!(e.contains("0 skin regions"), "{e}");
        let e = Regions::new(vec![skin1.clone(); MAX_REGIONS + 1], vec![])
            .unwrap_err()
            .to_string();
        assert!(e.contains("9 skin regions"), "{e}");
        let e = Regions::new(vec![skin1.clone()], vec![0, 1])
            .unwrap_err()
            .to_string();
        assert!(e.contains("triangle 1 is in skin region 1"), "{e}");
        let burley = p(ProfileKind::Burley, Material::SKIN2);
        let e = Regions::new(vec![skin1, burley], vec![0])
            .unwrap_err()
            .to_string();
        assert!(e.contains("mix the Dipole and Burley"), "{e}");
    }
}
