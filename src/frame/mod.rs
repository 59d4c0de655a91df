//! The character frame: one animated character rendered per frame on the GPU, every kernel
//! driven through the public kernel API as an outside renderer would drive it.
//!
//! One frame, recorded into one command buffer (barriers between kernels come from each
//! pass's declared accesses through the recorder's tracking):
//! 1. `pose` skins the whole character once (skin parts first, then cloth parts);
//!    `ao` skins the sphere tree from the same pose (and computes AO's per-vertex occlusion
//!    where a stage reads it: [`FrameConfig::ao_visibility`]);
//! 2. `raster` writes the screen G-buffer of the posed character; with culling and skin,
//!    `compose classify` splits the rasteriser's tiles by whether they hold a skin pixel; with an
//!    environment too, `compose need` marks the skin's atlas segments the compose pass reads,
//!    `sss` builds the skin's texture-space geometry from the posed buffers and its reach
//!    (the segments the diffusion of the needed ones reads, and the skin triangles they lie
//!    in: [`SssKernel::set_reach`]), then `vertex mark` and `vertex list` list the vertices
//!    the frame reads (those of the covered triangles and of the reach's,
//!    [`crate::kernels::raster::vertices`]); `env` rotates the environment's SG lobes and
//!    shadows each by the sphere tree's caps per vertex (visibility per lobe, shadowed
//!    irradiance), on that list when there is one;
//! 3. `sss` computes the skin's irradiance (lights with shadows, plus the shadowed
//!    environment; on the reach when there is one) and the subsurface diffusion;
//! 4. `btf` shades the cloth pixels of the G-buffer: the directional lights, then the
//!    environment's lobes with their per-vertex visibility through the BTF's light basis
//!    (`btf env basis`, [`crate::kernels::btf::basis`]);
//! 5. `compose` shades the skin pixels through the G-buffer (diffusion with Fresnel, a
//!    specular layer; with culling, over the skin's tiles only), takes the cloth's radiance,
//!    a background colour behind, tone maps.
//!
//! What is built once per character ([`CharacterFrame::new`]): the sphere tree, the skin's
//! UV layout and texture-space structure, the BTF tile, the camera framing the whole
//! animation.

use crate::error::{Error, Result};
use crate::gpu::{Context, Recorder, Timings};
use crate::kernels::btf::dirs::{Maps, Triangulation};
use crate::kernels::btf::gpu::{BtfKernel, Prepared as BtfPrepared};
use crate::kernels::btf::pack::{BtfInputs, Texture};
use crate::kernels::btf::synth::Btf;
use crate::kernels::compose::gpu::{NeedKernel, TileClassInputs, TileClassKernel};
use crate::kernels::compose::{self, ComposeKernel, ComposeOutput, FrameParams, SkinSpecular};
use crate::kernels::raster::gpu::{Posed as RasterPosed, Prepared as RasterPrep, RasterKernel};
use crate::kernels::raster::pack::{Camera as RasterCamera, key_triangle};
use crate::kernels::raster::vertices::VertexListKernel;
use crate::kernels::sss::gpu::{PosedBuffers, ReachMarks, SssKernel};
use crate::kernels::sss::profile::{Material, Profile, ProfileKind};
use crate::kernels::sss::{Light as SssLight, SamplerParams};
use crate::kernels::{Kernel, ao, pose};
use crate::scene::gbuffer::{Camera as BtfCamera, Frame as BtfFrame, GBuffer, Light};
use crate::scene::spheretree::{BuildConfig, SphereTree};
use crate::scene::texspace::TexGeometry;
use crate::scene::{Animation, Character};
use glam::{Mat3, Vec3};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// A directional light of the frame: direction towards the light, irradiance on a surface
/// facing it (linear rgb).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct DirLight {
    pub toward: [f32; 3],
    pub irradiance: [f32; 3],
}

/// What a character frame is built from.
#[derive(Clone, Debug, serde::Serialize)]
pub struct FrameConfig {
    /// The skinned glTF character.
    pub mesh: PathBuf,
    /// Its parts rendered as skin (node or mesh names).
    pub skin: Vec<String>,
    /// Its parts rendered as cloth.
    pub cloth: Vec<String>,
    /// The animation played.
    pub anim: String,
    /// Output width and height.
    pub size: [u32; 2],
    /// The skin's texture-space atlas side.
    pub atlas: u32,
    /// Diffusion samples per texel.
    pub samples: u32,
    /// Millimetres per model unit (the diffusion profile is in mm).
    pub mm_per_unit: f64,
    /// BTF tile repeats per unit of the cloth's uv.
    pub tile_scale: f32,
    /// A measured or synthesised BTF directory (`btf synth` layout); None: a woven tile is
    /// synthesised in memory.
    pub btf: Option<PathBuf>,
    /// Texels of the synthesised tile's side.
    pub btf_tile: u32,
    /// Directional lights (1..=2).
    pub lights: Vec<DirLight>,
    /// Radiance multiplier before tone mapping.
    pub exposure: f32,
    /// The skin's specular layer.
    pub specular: SkinSpecular,
    /// Background colour (linear).
    pub background: [f32; 3],
    /// An HDR environment map (EXR or .hdr), fitted once with `env_lobes` spherical
    /// Gaussians, rotated per frame on the GPU and shadowed by the character; None: the
    /// directional lights alone.
    pub env: Option<PathBuf>,
    /// Lobes of the environment's fit.
    pub env_lobes: usize,
    /// Width of the map the fit samples (the map is downsampled to it).
    pub env_fit_width: u32,
    /// How negative samples of the map (codec ringing) are treated.
    pub env_hdr: crate::scene::envmap::HdrPolicy,
    /// What turns the environment's per-lobe split into visibility: rays traced through the
    /// posed mesh every frame, grid^2 per vertex, correcting each lobe (`Some(grid)`,
    /// 1..=16), or AO's visibility as a scale (`None`)
    /// (see [`crate::kernels::env::EnvVisibility`]).
    pub env_trace_grid: Option<u32>,
    /// Rays per vertex of AO's static correction, baked once in the bind pose
    /// ([`ao::Correction`]: the detail the spheres miss, such as the skin buried under the
    /// clothes); 0: AO and the environment's shadowing by the spheres alone. It scales AO's
    /// visibility only, so it is baked only where the frame computes that
    /// ([`FrameConfig::ao_visibility`], or the environment scaled by AO's visibility).
    pub ao_correction_rays: usize,
    /// Where the parts' colours come from.
    pub materials: Materials,
    /// Cloth parts with their own BTF or tile scale; the other cloth parts take `btf` (or
    /// the synthesised weave) and `tile_scale`.
    pub cloth_parts: Vec<ClothPart>,
    /// The skin's scattering material (per mm; Jensen's measured skin 1 by default), for the
    /// skin parts without their own.
    pub skin_material: Material,
    /// Skin parts with their own scattering material: multi-region skin, a dipole profile
    /// per distinct material, each texel diffusing with its own part's profile
    /// ([`crate::kernels::sss::regions`]).
    pub skin_parts: Vec<SkinPart>,
    /// Work only where the camera looks (the default): with an environment, the skin's
    /// diffusion runs on the atlas segments the compose pass will read (pass `compose
    /// need`, over the tiles holding a skin pixel: `compose classify`), and the compose pass
    /// shades the rasteriser's listed tiles (the skin's shading only over the listed tiles
    /// holding a skin pixel), storing the background in the others only on frames when it
    /// changed (pass `compose background`).
    /// Off: every segment and every pixel. The images are the same either way (bit for
    /// bit). With an environment it also shades
    /// only the vertices the frame reads (those of the triangles covering a pixel and of the
    /// skin triangles the diffusion reads through its irradiance: passes `sss reach *`,
    /// `vertex mark` and `vertex list`, then `env trace` and `env shadow` over that list),
    /// unless [`FrameConfig::env_every_vertex`], and the skin's irradiance only on the
    /// segments that diffusion reads.
    pub cull: bool,
    /// The environment's passes shade every vertex even when culling (`frame --reference`
    /// sets it: it compares, and writes, every vertex's environment irradiance).
    pub env_every_vertex: bool,
    /// Computes AO's per-vertex visibility every frame (pass `ao occlusion`;
    /// [`Stages::ao`]) even when no stage reads it. The image reads it only where the
    /// environment takes AO's visibility as its scale (`env_trace_grid: None`), and then the
    /// pass always runs; with traced visibility (the default) the environment's shadow pass
    /// walks the sphere tree's cut itself and AO's visibility reaches no pixel, so by default
    /// the frame skins the sphere tree (`ao skin`) and skips the pass. `frame --reference`
    /// sets it (the AO-weighted floor is reported beside the environment's error).
    pub ao_visibility: bool,
    /// The cloth's environment (`btf env basis`) looks up this many of the brightest lobes
    /// ([`crate::kernels::btf::basis::brightest_lobes`]) at each pixel and interpolates the
    /// others' light factors from the cloth's vertices (pass `btf env vertices`, computed
    /// once a vertex in its own tangent frame); at least the lobe count: every lobe at
    /// every pixel, no vertex pass. The interpolation misses how the tangent frame turns
    /// across a triangle: on the demo's 16 lobes the cloth's environment against the BTF's
    /// own quadrature reads ~4% with 0 (the default), ~3% with 4, ~2% with all, and the
    /// pass costs ~2.6 ms less on a 2-core lavapipe VM with 0 than with all.
    pub cloth_pixel_lobes: usize,
    /// The texel format the cloth's BTFs are packed in for `btf shade`
    /// ([`Texture`]): `Block` (the default) is decoded and filtered by
    /// the shader from one fetch per tap; the sampled formats run lavapipe's software sRGB
    /// (and BC1) decode on every filtered texel, ~3x the pass's time there (`bench frame`:
    /// `btf shade` 10.2 ms with `Rgba8`, see the CHANGELOG).
    pub cloth_texture: Texture,
}

/// A skin part's own scattering material ([`FrameConfig::skin_parts`]).
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct SkinPart {
    /// The part (one of [`FrameConfig::skin`]).
    pub part: String,
    /// Its material.
    pub material: Material,
}

/// Parses a command line's skin material: a built-in name (`skin1`, `skin2`: Jensen et al.
/// 2001's measured skins) or custom coefficients per mm, `SA_R,SA_G,SA_B/SS_R,SS_G,SS_B`
/// (sigma_a, then sigma_s'), optionally `/ETA`.
pub fn parse_skin_material(s: &str) -> Result<Material> {
    let s = s.trim();
    if !s.contains('/') {
        return Material::named(s);
    }
    let bad = |why: String| {
        Error::InvalidArgument(format!(
            "skin material '{s}': {why} (expected skin1, skin2 or SA_R,SA_G,SA_B/SS_R,SS_G,SS_B\
             [/ETA], per mm)"
        ))
    };
    let parts: Vec<&str> = s.split('/').collect();
    if parts.len() > 3 {
        return Err(bad(format!("{} '/'-separated fields", parts.len())));
    }
    let rgb = |f: &str, what: &str| -> Result<[f64; 3]> {
        let v: Vec<&str> = f.split(',').map(str::trim).collect();
        if v.len() != 3 {
            return Err(bad(format!("{what} has {} values, not 3", v.len())));
        }
        let mut out = [0.0; 3];
        for (o, x) in out.iter_mut().zip(&v) {
            *o = x
                .parse::<f64>()
                .map_err(|_| bad(format!("{what}: '{x}' is not a number")))?;
        }
        Ok(out)
    };
    let sigma_a = rgb(parts[0], "sigma_a")?;
    let sigma_s = rgb(parts[1], "sigma_s'")?;
    let eta = match parts.get(2) {
        Some(e) => e
            .trim()
            .parse::<f64>()
            .map_err(|_| bad(format!("eta '{e}' is not a number")))?,
        None => crate::kernels::sss::profile::DEFAULT_ETA,
    };
    Material::custom(sigma_a, sigma_s, eta).map_err(|e| match e {
        Error::InvalidArgument(m) => bad(m),
        other => other,
    })
}

/// A cloth part's own BTF and tile scale ([`FrameConfig::cloth_parts`]).
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct ClothPart {
    /// The part (one of [`FrameConfig::cloth`]).
    pub part: String,
    /// Its BTF; None: the frame's default.
    pub btf: Option<BtfSource>,
    /// Its BTF tile repeats per unit of its uv; None: the frame's `tile_scale`.
    pub tile_scale: Option<f32>,
}

/// Where a cloth BTF comes from.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum BtfSource {
    /// A tile of this pattern synthesised in memory (`btf synth`'s model, `btf_tile` texels
    /// a side).
    Synthesized(crate::kernels::btf::cloth::Pattern),
    /// A measured or synthesised BTF directory (`btf synth` layout).
    Directory(PathBuf),
}

impl std::fmt::Display for BtfSource {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            BtfSource::Synthesized(p) => write!(f, "synthesised {}", p.name()),
            BtfSource::Directory(d) => write!(f, "{}", d.display()),
        }
    }
}

impl BtfSource {
    /// Parses a command line's BTF: a pattern name (`weave`, `knit`, `rib`) or a directory.
    pub fn parse(s: &str) -> BtfSource {
        use crate::kernels::btf::cloth::Pattern;
        match [Pattern::Weave, Pattern::Knit, Pattern::Rib]
            .into_iter()
            .find(|p| p.name() == s)
        {
            Some(p) => BtfSource::Synthesized(p),
            None => BtfSource::Directory(PathBuf::from(s)),
        }
    }

    /// Loads or synthesises the BTF (`tile`: the synthesised tile's side).
    pub fn load(&self, tile: u32) -> Result<Btf> {
        use crate::kernels::btf::cloth::SynthConfig;
        match self {
            BtfSource::Synthesized(p) => {
                crate::kernels::btf::synth::synthesize(&SynthConfig::tile(*p, tile))
            }
            BtfSource::Directory(d) => crate::kernels::btf::load::load_dir(d),
        }
    }
}

/// Where the parts' colours come from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Materials {
    /// Each part's glTF base colour (factor times the sRGB texture at the mesh's uv, glTF's
    /// white where the part has no material) is its albedo. Skin: the diffuse exit times
    /// albedo / R_tot (the dipole profile's total reflectance divided out: the profile then
    /// sets how far light spreads, the texture its colour; applied after the diffusion, as
    /// d'Eon and Luebke's post-scatter texturing). Cloth: the BTF radiance times albedo / the
    /// BTF's own albedo ([`crate::kernels::btf::env::albedo`]), so the weave and its angular
    /// behaviour stay and its mean colour becomes the authored one.
    Gltf,
    /// The skin profile's measured colour and the BTF's own; the glTF's materials are not
    /// read.
    Measured,
}

impl Default for FrameConfig {
    fn default() -> Self {
        FrameConfig {
            mesh: PathBuf::from(crate::kernels::sss::DEFAULT_MESH),
            skin: vec!["Head".into()],
            cloth: vec!["Torso".into(), "Legs".into()],
            anim: "Epileptisch".into(),
            size: [512, 512],
            atlas: 512,
            samples: 32,
            mm_per_unit: crate::kernels::sss::DEFAULT_MESH_MM_PER_UNIT,
            tile_scale: 20.0,
            btf: None,
            btf_tile: 16,
            lights: vec![
                DirLight {
                    toward: [0.5, 0.8, 0.6],
                    irradiance: [2.6, 2.45, 2.3],
                },
                DirLight {
                    toward: [-0.9, 0.1, 0.2],
                    irradiance: [0.6, 0.7, 1.0],
                },
            ],
            exposure: 1.0,
            specular: SkinSpecular::default(),
            background: [0.05, 0.055, 0.06],
            env: Some(PathBuf::from(crate::kernels::srbf::DEFAULT_ENV)),
            env_lobes: 16,
            env_fit_width: 128,
            env_hdr: Default::default(),
            env_trace_grid: Some(crate::kernels::env::DEFAULT_TRACE_GRID),
            ao_correction_rays: 1024,
            materials: Materials::Gltf,
            cloth_parts: Vec::new(),
            skin_material: Material::SKIN1,
            skin_parts: Vec::new(),
            cull: true,
            env_every_vertex: false,
            cloth_pixel_lobes: 0,
            ao_visibility: false,
            cloth_texture: Texture::Block,
        }
    }
}

impl FrameConfig {
    /// Whether the cloth's environment interpolates light factors from the vertices (pass
    /// `btf env vertices`) for a basis of `lobes` lobes: unless every lobe is looked up per
    /// pixel ([`FrameConfig::cloth_pixel_lobes`]).
    pub fn cloth_light_per_vertex(&self, lobes: usize) -> bool {
        self.cloth_pixel_lobes < lobes
    }

    /// The part ids of the cloth (they follow the skin parts' ids), as a mask: bit p for
    /// part p ([`FrameConfig::check`] keeps every id below 32).
    pub fn cloth_part_mask(&self) -> u32 {
        let skin = self.skin.len() as u32;
        (skin..skin + self.cloth.len() as u32).fold(0u32, |m, p| m | (1 << p))
    }

    /// Each cloth part's BTF and tile scale, in [`FrameConfig::cloth`]'s order (its
    /// [`ClothPart`] where it has one, else the frame's defaults).
    pub fn cloth_materials(&self) -> Result<Vec<(BtfSource, f32)>> {
        for (i, cp) in self.cloth_parts.iter().enumerate() {
            if !self.cloth.contains(&cp.part) {
                return Err(Error::InvalidArgument(format!(
                    "cloth part '{}' has a BTF or tile scale but is not one of the cloth parts {:?}",
                    cp.part, self.cloth
                )));
            }
            if self.cloth_parts[..i].iter().any(|o| o.part == cp.part) {
                return Err(Error::InvalidArgument(format!(
                    "cloth part '{}' is given its BTF or tile scale twice",
                    cp.part
                )));
            }
            if let Some(t) = cp.tile_scale
                && !(t.is_finite() && t > 0.0)
            {
                return Err(Error::InvalidArgument(format!(
                    "cloth part '{}': tile scale {t} must be > 0",
                    cp.part
                )));
            }
        }
        let default = match &self.btf {
            Some(d) => BtfSource::Directory(d.clone()),
            None => BtfSource::Synthesized(crate::kernels::btf::cloth::Pattern::Weave),
        };
        Ok(self
            .cloth
            .iter()
            .map(|name| {
                let own = self.cloth_parts.iter().find(|c| &c.part == name);
                (
                    own.and_then(|c| c.btf.clone())
                        .unwrap_or_else(|| default.clone()),
                    own.and_then(|c| c.tile_scale).unwrap_or(self.tile_scale),
                )
            })
            .collect())
    }

    /// Each skin part's material, in [`FrameConfig::skin`]'s order (its [`SkinPart`] where it
    /// has one, else `skin_material`), checked.
    pub fn skin_materials(&self) -> Result<Vec<Material>> {
        for (i, sp) in self.skin_parts.iter().enumerate() {
            if !self.skin.contains(&sp.part) {
                return Err(Error::InvalidArgument(format!(
                    "skin part '{}' has a scattering material but is not one of the skin parts \
                     {:?}",
                    sp.part, self.skin
                )));
            }
            if self.skin_parts[..i].iter().any(|o| o.part == sp.part) {
                return Err(Error::InvalidArgument(format!(
                    "skin part '{}' is given its scattering material twice",
                    sp.part
                )));
            }
        }
        let out: Vec<Material> = self
            .skin
            .iter()
            .map(|name| {
                self.skin_parts
                    .iter()
                    .find(|s| &s.part == name)
                    .map_or(self.skin_material, |s| s.material)
            })
            .collect();
        for m in out.iter().chain([&self.skin_material]) {
            m.check()?;
        }
        let mut distinct: Vec<Material> = Vec::new();
        for m in &out {
            if !distinct.contains(m) {
                distinct.push(*m);
            }
        }
        if distinct.len() > crate::kernels::sss::regions::MAX_REGIONS {
            return Err(Error::InvalidArgument(format!(
                "{} distinct skin materials; the skin takes at most {}",
                distinct.len(),
                crate::kernels::sss::regions::MAX_REGIONS
            )));
        }
        Ok(out)
    }

    /// Checks what can be checked without reading the files.
    pub fn check(&self) -> Result<()> {
        let bad = |m: String| Err(Error::InvalidArgument(m));
        if self.skin.is_empty() && self.cloth.is_empty() {
            return bad("a frame needs at least one skin or cloth part".into());
        }
        if self.lights.is_empty() || self.lights.len() > compose::pack::MAX_LIGHTS {
            return bad(format!(
                "{} lights; a frame takes 1..={}",
                self.lights.len(),
                compose::pack::MAX_LIGHTS
            ));
        }
        for l in &self.lights {
            let t = Vec3::from_array(l.toward);
            if !t.is_finite()
                || t.length() < 1e-6
                || l.irradiance.iter().any(|c| !c.is_finite() || *c < 0.0)
            {
                return bad(format!(
                    "light {l:?}: direction finite, non-zero; irradiance >= 0"
                ));
            }
        }
        if !(self.mm_per_unit.is_finite() && self.mm_per_unit > 0.0) {
            return bad(format!("mm per unit {} must be > 0", self.mm_per_unit));
        }
        if self.env.is_some() && !(1..=crate::kernels::env::MAX_LOBES).contains(&self.env_lobes) {
            return bad(format!(
                "{} environment lobes; 1..={}",
                self.env_lobes,
                crate::kernels::env::MAX_LOBES
            ));
        }
        if let Some(g) = self.env_trace_grid
            && !(1..=crate::kernels::env::MAX_TRACE_GRID).contains(&g)
        {
            return bad(format!(
                "environment trace grid {g}; 1..={} (or none: AO's visibility)",
                crate::kernels::env::MAX_TRACE_GRID
            ));
        }
        if !(self.tile_scale.is_finite() && self.tile_scale > 0.0) {
            return bad(format!("tile scale {} must be > 0", self.tile_scale));
        }
        self.cloth_materials()?;
        self.skin_materials()?;
        if self.ao_correction_rays > 1 << 20 {
            return bad(format!(
                "{} AO correction rays a vertex; at most 1048576 (0: off)",
                self.ao_correction_rays
            ));
        }
        // Part ids travel in the G-buffer and the cloth's environment pass selects them by
        // a 32-bit mask.
        if self.skin.len() + self.cloth.len() > 32 {
            return bad(format!(
                "{} skin and {} cloth parts; a frame takes at most 32 in all",
                self.skin.len(),
                self.cloth.len()
            ));
        }
        Ok(())
    }
}

/// One frame's input.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FrameInput {
    /// Animation time in seconds (wrapped into the animation).
    pub time: f32,
    /// The environment's rotation.
    pub env_rotation: Mat3,
}

/// The labels of a frame's passes, in order, each once (their GPU times are in a frame's
/// timings, summed over a label's passes: see [`CharacterFrame::passes_by_name`]).
pub fn pass_names(frame: &CharacterFrame) -> Vec<&'static str> {
    frame.passes_by_name().into_iter().map(|p| p.name).collect()
}

struct Skin {
    kernel: SssKernel,
    geo: TexGeometry,
    lights: Vec<SssLight>,
    /// Pass `compose need`: the atlas segments the compose pass reads this frame, to which
    /// the diffusion is restricted (with an environment: the diffusion of a per-vertex
    /// irradiance is the one that takes the bitmap).
    need: Option<NeedKernel>,
}

/// The cloth parts sharing one BTF.
struct ClothGroup {
    /// Where the BTF came from.
    source: BtfSource,
    /// Bit p: part p (the G-buffer's id) is shaded with this BTF.
    part_mask: u32,
    /// The BTF on the host (for the twins).
    btf: Btf,
    /// Its light basis and lobe tables (with an environment).
    basis: Option<crate::kernels::btf::basis::BasisData>,
    kernel: BtfKernel,
}

/// Setup costs and sizes, for reports.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct SetupReport {
    pub vertices: usize,
    pub triangles: usize,
    pub skin_triangles: usize,
    pub cloth_triangles: usize,
    pub spheres: usize,
    pub atlas_covered_texels: usize,
    pub ms_tree: f64,
    pub ms_atlas: f64,
    pub ms_btf: f64,
    pub ms_upload: f64,
    pub env_lobes: usize,
    /// Relative L2 of the environment's fit (solid-angle weighted, all channels).
    pub env_fit_rel_l2: f64,
    pub ms_env_fit: f64,
    /// The cloth's light basis: its share of the lit BTF's energy (the lowest over the
    /// cloth's BTFs), and its setup time (all of them).
    pub cloth_basis_captured: f64,
    pub ms_cloth_basis: f64,
    /// Baking AO's static correction.
    pub ms_ao_correction: f64,
    /// Per part (skin then cloth), the colour it was given.
    pub materials: Vec<String>,
}

/// The character frame: every kernel of one animated character, built once.
pub struct CharacterFrame {
    /// The character (skin parts then cloth parts, joined).
    pub character: Character,
    /// Part index of every triangle (skin parts first).
    pub parts: Vec<u32>,
    anim: usize,
    /// The camera, framing the character over its whole animation.
    pub camera: RasterCamera,
    cfg: FrameConfig,
    pose: pose::PoseKernel,
    ao: ao::gpu::AoKernel,
    raster: RasterKernel,
    /// With culling and skin: the rasteriser's tiles split by whether they hold a skin pixel
    /// (pass `compose classify`), for `compose need` and the compose pass.
    classify: Option<TileClassKernel>,
    /// The vertices the environment's passes shade this frame (with culling).
    vertices: Option<VertexListKernel>,
    env: Option<crate::kernels::env::EnvKernel>,
    sss: Option<Skin>,
    /// One group per distinct BTF of the cloth parts, each shading its own parts into
    /// `cloth_result`.
    cloth: Vec<ClothGroup>,
    /// The cloth's radiance per pixel, written by every group's passes.
    cloth_result: Option<crate::gpu::Buffer>,
    /// The direction maps (one set serves every BTF; kept on the host for the twins).
    cloth_maps: Option<Maps>,
    btf_frame: BtfFrame,
    compose: ComposeKernel,
    compose_prep: compose::Prepared,
    /// What setup cost.
    pub setup: SetupReport,
}

/// The compose pass's surface per part (skin then cloth) under `cfg.materials`, and a line
/// per part saying what it got. Skin divides out its profile's total reflectance (`r_tot`,
/// per skin part), cloth the BTF's albedo (see [`Materials::Gltf`]).
fn surfaces(
    cfg: &FrameConfig,
    names: &[&str],
    r_tot: &[[f64; 3]],
    cloth_albedo: &[[f64; 3]],
    uv_scales: &[f32],
    lines: &mut Vec<String>,
) -> Result<Vec<compose::pack::Surface>> {
    if cfg.materials == Materials::Measured {
        lines.push("materials: the skin profile's and the BTF's own colours".into());
        return Ok(Vec::new());
    }
    let mats = load_materials(&cfg.mesh, names)?;
    let mut out = Vec::with_capacity(mats.len());
    for (p, (m, name)) in mats.iter().zip(names).enumerate() {
        let (own, what) = if p < cfg.skin.len() {
            (r_tot[p], "the skin profile's total reflectance")
        } else {
            (cloth_albedo[p - cfg.skin.len()], "the BTF's albedo")
        };
        // Below this an albedo channel cannot be rescaled to the authored colour without
        // amplifying the BTF's noise or the profile's rounding by more than 1000x.
        if own.iter().any(|c| !(c.is_finite() && *c >= 1e-3)) {
            return Err(Error::input(
                &cfg.mesh,
                format!(
                    "part '{name}': {what} {own:?} is too dark in a channel to carry the \
                     glTF base colour; use the measured materials instead"
                ),
            ));
        }
        let scale = [0, 1, 2].map(|c| (m.factor[c] as f64 / own[c]) as f32);
        let texture = match &m.texture {
            Some(t) => format!("{} ({} x {})", t.source, t.width, t.height),
            None => "no texture".into(),
        };
        lines.push(format!(
            "material of {name}: '{}', base colour factor [{:.3}, {:.3}, {:.3}], {texture}",
            m.name, m.factor[0], m.factor[1], m.factor[2]
        ));
        out.push(compose::pack::Surface {
            scale,
            uv_scale: uv_scales[p],
            texture: m.texture.clone(),
        });
    }
    Ok(out)
}

/// The glTF material of each named part (`scene::gltf_load::load_materials`; an error naming
/// the feature without `gltf`).
pub fn load_materials(
    mesh: &Path,
    names: &[&str],
) -> Result<Vec<crate::scene::material::Material>> {
    #[cfg(feature = "gltf")]
    {
        crate::scene::gltf_load::load_materials(mesh, names)
    }
    #[cfg(not(feature = "gltf"))]
    {
        let _ = names;
        Err(Error::feature(
            format!("loading the materials of {}", mesh.display()),
            "gltf",
        ))
    }
}

/// The named parts of a glTF character joined into one mesh, with a part id per triangle
/// (`scene::gltf_load::load_parts`; an error naming the feature without `gltf`).
pub fn load_parts(mesh: &Path, names: &[&str]) -> Result<(Character, Vec<u32>)> {
    #[cfg(feature = "gltf")]
    {
        crate::scene::gltf_load::load_parts(mesh, names)
    }
    #[cfg(not(feature = "gltf"))]
    {
        let _ = names;
        Err(Error::feature(
            format!("loading the character parts of {}", mesh.display()),
            "gltf",
        ))
    }
}

/// The index of the animation `name` (`Character::animation`'s lookup), the error naming
/// the file.
pub fn animation_index(c: &Character, name: &str, path: &Path) -> Result<usize> {
    let a = c
        .animation(name)
        .map_err(|e| Error::input(path, e.to_string()))?;
    c.animations
        .iter()
        .position(|b| std::ptr::eq(a, b))
        .ok_or_else(|| Error::input(path, format!("animation '{name}' not in the list")))
}

/// The bounds of the posed vertices over 16 poses spread across animation `anim` (CPU, once:
/// a fixed camera that keeps the character in view).
pub fn animation_bounds(c: &Character, prep: &pose::Prepared, anim: usize) -> Result<(Vec3, Vec3)> {
    let a = &c.animations[anim];
    let (mut lo, mut hi) = (Vec3::splat(f32::MAX), Vec3::splat(f32::MIN));
    for i in 0..16 {
        let m = c
            .rig
            .skinning_matrices(Some(a), a.duration * i as f32 / 16.0);
        let p = pose::cpu::pose(prep, &m)?;
        let (l, h) = crate::scene::mesh::bounds(&p.positions);
        (lo, hi) = (lo.min(l), hi.max(h));
    }
    Ok((lo, hi))
}

/// The skinning matrices of animation `anim` at `time` seconds, wrapped into the animation.
pub fn looped_matrices(c: &Character, anim: usize, time: f32) -> Vec<glam::Mat4> {
    let a = &c.animations[anim];
    let t = if a.duration > 0.0 {
        time.rem_euclid(a.duration)
    } else {
        0.0
    };
    c.rig.skinning_matrices(Some(a), t)
}

/// Resolution of the cloth's direction maps.
pub const CLOTH_MAP_RES: u32 = 128;

/// The cloth stage's CPU twins on a frame's stages ([`CharacterFrame::cloth_twins`]).
pub struct ClothTwins {
    /// Bit p: part p is cloth.
    pub part_mask: u32,
    /// `btf shade` (the directional lights) per pixel, and where f32 may differ.
    pub direct: Vec<[f64; 4]>,
    pub direct_ambiguous: Vec<bool>,
    /// `btf env basis` per pixel (zero without an environment).
    pub env: crate::kernels::btf::basis::Shaded,
    /// The exact pass's twin on the same lobes and interpolated visibility: the BTF's own
    /// quadrature of the fitted environment (81 cell factors per pixel); None without an
    /// environment.
    pub quadrature: Option<Vec<[f64; 4]>>,
}

/// The cloth stage's errors at one pose ([`CharacterFrame::cloth_errors`]).
#[derive(Clone, Copy, Debug, serde::Serialize)]
pub struct ClothErrors {
    /// Cloth pixels compared.
    pub pixels: usize,
    /// The environment's share of the cloth's light.
    pub env_share: f64,
    /// The light basis against the BTF's own quadrature (relative L2 over the cloth).
    pub basis_vs_quadrature: f64,
    /// The GPU's cloth against the twins (relative L2).
    pub gpu_vs_twins: f64,
}

/// A woven cloth tile synthesised in memory (`btf synth`'s model, one ray per texel).
pub fn synthesized_btf(tile: u32) -> Result<Btf> {
    BtfSource::Synthesized(crate::kernels::btf::cloth::Pattern::Weave).load(tile)
}

impl CharacterFrame {
    /// Loads the character, builds what is fixed per character, creates every kernel and
    /// uploads their static data (submitted and waited for here).
    pub fn new(
        ctx: &Context,
        cfg: &FrameConfig,
        progress: &mut dyn FnMut(&str),
    ) -> Result<CharacterFrame> {
        cfg.check()?;
        let mut setup = SetupReport::default();
        let names: Vec<&str> = cfg
            .skin
            .iter()
            .chain(&cfg.cloth)
            .map(String::as_str)
            .collect();
        let (character, parts) = load_parts(&cfg.mesh, &names)?;
        let anim = animation_index(&character, &cfg.anim, &cfg.mesh)?;
        let skin_parts = cfg.skin.len() as u32;
        let skin_triangles = parts.iter().take_while(|&&p| p < skin_parts).count();
        if parts[skin_triangles..].iter().any(|&p| p < skin_parts) {
            return Err(Error::input(
                &cfg.mesh,
                "the skin parts' triangles are not first in the joined mesh",
            ));
        }
        let mesh = &character.mesh;
        setup.vertices = mesh.positions.len();
        setup.triangles = mesh.triangles.len();
        setup.skin_triangles = skin_triangles;
        setup.cloth_triangles = mesh.triangles.len() - skin_triangles;
        progress(&format!(
            "{}: {} vertices, {} triangles ({} skin, {} cloth), animation '{}' ({:.2} s)",
            cfg.mesh.display(),
            setup.vertices,
            setup.triangles,
            setup.skin_triangles,
            setup.cloth_triangles,
            character.animations[anim].name,
            character.animations[anim].duration
        ));
        let joints = character.rig.joints.len();
        let pose_prep = pose::Prepared::new(mesh, joints)?;
        // The camera frames the character's bounds over the animation.
        let (lo, hi) = animation_bounds(&character, &pose_prep, anim)?;
        // The bounds' largest extent across the view (it looks along -z), not their
        // diagonal: the character fills more of the image.
        let e = hi - lo;
        let camera = RasterCamera::framing(
            (lo + hi) * 0.5,
            0.5 * e.x.max(e.y).max(0.6 * e.z),
            Vec3::new(0.25, 0.15, 1.0),
        );
        // The sphere tree of the whole character (AO, and the environment's occluders).
        let t = Instant::now();
        let (tree, _) = SphereTree::build(mesh, &BuildConfig::default())?;
        let ao_prep = ao::pack::Prepared::new(mesh, &tree, joints)?;
        setup.spheres = tree.spheres.iter().filter(|s| s.used()).count();
        setup.ms_tree = t.elapsed().as_secs_f64() * 1e3;
        progress(&format!(
            "sphere tree: {} spheres ({:.0} ms)",
            setup.spheres, setup.ms_tree
        ));
        // AO's per-vertex visibility runs where a stage reads it: the environment scaled by
        // it (the traced environment walks the sphere tree's cut itself), or the caller.
        let env_reads_ao = cfg.env.is_some() && cfg.env_trace_grid.is_none();
        let ao_occlusion = cfg.ao_visibility || env_reads_ao;
        // AO's static correction, as `vkshade ao` and `vkshade env` bake it: without it the
        // skin under the clothes reads as half open and takes the environment's light. It
        // scales AO's visibility only, so it is baked only when that is computed.
        let t = Instant::now();
        let ao_params = ao::AoParams::default();
        let correction = if ao_occlusion && cfg.ao_correction_rays > 0 {
            let c = ao::Correction::bake(mesh, cfg.ao_correction_rays);
            let cpu_ao = ao::cpu::CpuAo::new(ao::formula::OcclusionTable::new(
                ao::formula::TABLE_SIZE,
                ao::formula::TABLE_SIZE,
            ));
            Some(c.factors(&cpu_ao, &ao_prep, &ao_params))
        } else {
            None
        };
        setup.ms_ao_correction = t.elapsed().as_secs_f64() * 1e3;
        if correction.is_some() {
            progress(&format!(
                "AO correction: {} rays a vertex in the bind pose ({:.0} ms)",
                cfg.ao_correction_rays, setup.ms_ao_correction
            ));
        }
        // The skin's texture space: the skin parts alone, with the same vertex ids.
        let t = Instant::now();
        let skin_geo = if skin_triangles > 0 {
            let skin_names: Vec<&str> = cfg.skin.iter().map(String::as_str).collect();
            let (skin_char, _) = load_parts(&cfg.mesh, &skin_names)?;
            let n = skin_char.mesh.positions.len();
            if skin_char.mesh.positions[..] != mesh.positions[..n]
                || skin_char.mesh.triangles[..] != mesh.triangles[..skin_triangles]
            {
                return Err(Error::input(
                    &cfg.mesh,
                    "the skin parts alone differ from the joined mesh's first vertices",
                ));
            }
            let geo = TexGeometry::build(&skin_char.mesh, cfg.atlas, cfg.mm_per_unit)?;
            setup.atlas_covered_texels = geo.report.covered_texels;
            Some((geo, skin_char.mesh.positions))
        } else {
            None
        };
        setup.ms_atlas = t.elapsed().as_secs_f64() * 1e3;
        if skin_geo.is_some() {
            progress(&format!(
                "skin atlas {}^2: {} covered texels ({:.0} ms)",
                cfg.atlas, setup.atlas_covered_texels, setup.ms_atlas
            ));
        }
        // The cloth's BTFs: one per distinct source, each over the parts that use it.
        let t = Instant::now();
        let cloth_materials = cfg.cloth_materials()?;
        let mut groups: Vec<(BtfSource, u32)> = Vec::new();
        if setup.cloth_triangles > 0 {
            for (i, (source, _)) in cloth_materials.iter().enumerate() {
                let bit = 1u32 << (cfg.skin.len() + i);
                match groups.iter_mut().find(|(s, _)| s == source) {
                    Some((_, mask)) => *mask |= bit,
                    None => groups.push((source.clone(), bit)),
                }
            }
        }
        let btfs = groups
            .iter()
            .map(|(source, _)| source.load(cfg.btf_tile))
            .collect::<Result<Vec<Btf>>>()?;
        setup.ms_btf = t.elapsed().as_secs_f64() * 1e3;
        for ((source, mask), b) in groups.iter().zip(&btfs) {
            let parts: Vec<&str> = (0..32)
                .filter(|p| mask & (1 << p) != 0)
                .map(|p| names[p])
                .collect();
            progress(&format!(
                "BTF {source}: {} x {} texel tile, 81 x 81 directions, for {}",
                b.size[0],
                b.size[1],
                parts.join(", ")
            ));
        }
        if !btfs.is_empty() {
            progress(&format!("BTFs ready ({:.0} ms)", setup.ms_btf));
        }
        // Each part's raster uv multiplier: a cloth part's tile scale, the frame's for skin.
        let uv_scales: Vec<f32> = (0..names.len())
            .map(|p| match p.checked_sub(cfg.skin.len()) {
                Some(c) => cloth_materials[c].1,
                None => cfg.tile_scale,
            })
            .collect();
        let group_of_cloth = |c: usize| {
            groups
                .iter()
                .position(|(_, m)| m & (1 << (cfg.skin.len() + c)) != 0)
        };
        // The skin's regions: a dipole profile per distinct material, each skin triangle in
        // its part's.
        let skin_materials = cfg.skin_materials()?;
        let mut distinct: Vec<Material> = Vec::new();
        let region_of_part: Vec<u8> = skin_materials
            .iter()
            .map(|m| match distinct.iter().position(|d| d == m) {
                Some(r) => r as u8,
                None => {
                    distinct.push(*m);
                    (distinct.len() - 1) as u8
                }
            })
            .collect();
        let profiles = distinct
            .iter()
            .map(|m| {
                Profile::new(
                    ProfileKind::Dipole,
                    *m,
                    crate::kernels::sss::profile::DEFAULT_ENERGY,
                )
            })
            .collect::<Result<Vec<_>>>()?;
        let part_r_tot: Vec<[f64; 3]> = region_of_part
            .iter()
            .map(|&r| profiles[r as usize].r_tot)
            .collect();
        let skin_regions = crate::kernels::sss::Regions::new(
            profiles,
            parts[..skin_triangles]
                .iter()
                .map(|&p| region_of_part[p as usize])
                .collect(),
        )?;
        if skin_regions.len() > 1 {
            progress(&format!(
                "skin: {} scattering profiles ({})",
                skin_regions.len(),
                cfg.skin
                    .iter()
                    .zip(&skin_materials)
                    .map(|(p, m)| format!("{p} {}", m.name))
                    .collect::<Vec<_>>()
                    .join(", ")
            ));
        }
        // The parts' colours.
        let surfaces = surfaces(
            cfg,
            &names,
            &part_r_tot,
            &(0..cfg.cloth.len())
                .map(|c| {
                    group_of_cloth(c)
                        .map_or([1.0; 3], |g| crate::kernels::btf::env::albedo(&btfs[g]))
                })
                .collect::<Vec<_>>(),
            &uv_scales,
            &mut setup.materials,
        )?;
        for m in &setup.materials {
            progress(m);
        }
        // The environment, fitted once.
        let t = Instant::now();
        let lobes = match &cfg.env {
            Some(path) => {
                use crate::kernels::srbf::fit::{FitConfig, fit};
                let map = crate::scene::EnvMap::load_with(path, cfg.env_hdr)?;
                if let Some(r) = &map.repair {
                    progress(&format!("{}: {r}", path.display()));
                }
                let small = map.downsampled(cfg.env_fit_width.min(map.width))?;
                let fitted = fit(
                    &small.samples(),
                    &FitConfig {
                        lobes: cfg.env_lobes,
                        ..FitConfig::default()
                    },
                )?;
                setup.env_lobes = fitted.lobes.len();
                setup.env_fit_rel_l2 = fitted.rel_l2;
                Some(fitted.lobes)
            }
            None => None,
        };
        setup.ms_env_fit = t.elapsed().as_secs_f64() * 1e3;
        if let Some(path) = &cfg.env {
            progress(&format!(
                "environment {}: {} lobes, relative L2 {:.3} ({:.0} ms)",
                path.display(),
                setup.env_lobes,
                setup.env_fit_rel_l2,
                setup.ms_env_fit
            ));
        }
        crate::kernels::raster::gpu::check_device(ctx)?;
        let t = Instant::now();
        let mut rec = ctx.recorder("character frame setup")?;
        let pose = pose::PoseKernel::new(&mut rec, &pose_prep)?;
        let mut ao = ao::gpu::AoKernel::on_pose(&mut rec, &ao_prep, ao_params, &pose)?;
        ao.set_occlusion(ao_occlusion);
        if let Some(c) = &correction {
            ao.set_correction(&mut rec, c)?;
        }
        let rprep = RasterPrep::new(mesh, &parts, cfg.size, cfg.tile_scale)?
            .with_part_uv_scales(&uv_scales)?;
        let raster = RasterKernel::new(
            &mut rec,
            &rprep,
            &RasterPosed {
                positions: pose.positions(),
                normals: pose.normals(),
                tangents: pose.tangents(),
            },
        )?;
        // The vertices whose environment the frame reads: those of every triangle covering a
        // pixel (the cloth's and the skin's shading read them there) and those of the skin
        // triangles whose texture-space irradiance the skin's diffusion reads this frame
        // (the SSS reach marks them in the list's triangle bitmap: `sss reach triangles`).
        let mut vertices = match (&lobes, raster.tiles()) {
            (Some(_), Some(_)) if cfg.cull && !cfg.env_every_vertex => Some(VertexListKernel::new(
                &mut rec,
                &raster,
                &mesh.triangles,
                pose.vertex_count() as u32,
                &[],
                Some(&crate::geom::spatial_order(&mesh.positions)),
            )?),
            _ => None,
        };
        let env = match &lobes {
            Some(l) => Some(crate::kernels::env::EnvKernel::with_vertex_list(
                &mut rec,
                l,
                &pose,
                &ao,
                match cfg.env_trace_grid {
                    Some(grid) => crate::kernels::env::EnvVisibility::Traced {
                        rest: &mesh.positions,
                        triangles: &mesh.triangles,
                        grid,
                    },
                    None => crate::kernels::env::EnvVisibility::Ao,
                },
                vertices.as_ref().map(VertexListKernel::list),
            )?),
            None => None,
        };
        let lights_toward: Vec<Vec3> = cfg
            .lights
            .iter()
            .map(|l| Vec3::from_array(l.toward).normalize())
            .collect();
        // The compose pass's skin tables (pass `compose need` reads the same).
        let compose_base = match &skin_geo {
            Some((geo, _)) => compose::Prepared::new(cfg.size, geo)?,
            None => compose::Prepared::without_skin(cfg.size),
        };
        // With culling and skin: the tiles holding a skin pixel, apart, so that the skin's
        // shading runs only over them.
        let classify = match raster.tiles().filter(|_| cfg.cull) {
            Some(tiles) if compose_base.skin_triangles > 0 => Some(TileClassKernel::new(
                &mut rec,
                &compose_base,
                &TileClassInputs {
                    keys: raster.keys(),
                    tiles,
                },
            )?),
            _ => None,
        };
        let sss = match &skin_geo {
            Some((geo, rest)) => {
                // No thin-part transmission: the compose pass does not read it (the skin's
                // light is the diffusion's, with the entry and exit Fresnel), and it cost
                // `sss vertex light` a thickness ray per vertex and light and `sss
                // irradiance` three loads and a store per texel: ~2 ms of the frame on a
                // 2-core VM (`bench frame`, alternated).
                let params = SamplerParams {
                    samples: cfg.samples,
                    transmission: false,
                    ..SamplerParams::default()
                };
                let src = PosedBuffers {
                    positions: pose.positions(),
                    normals: pose.normals(),
                    mm_per_unit: cfg.mm_per_unit as f32,
                };
                let mut kernel =
                    SssKernel::new_posed(&mut rec, geo, rest, &skin_regions, params, src)?;
                // The environment's shadowed irradiance joins the lights' before diffusion
                // (so its visibility bleeds with the light, and no AO is applied after).
                if let Some(e) = &env {
                    kernel.set_vertex_irradiance(&mut rec, Some(e.irradiance()))?;
                }
                // The diffusion runs only on the atlas segments the compose pass will read
                // this frame (every skin pixel's bilinear footprint and a texel around it),
                // marked from the G-buffer after the raster passes.
                let need = match (&env, &classify) {
                    (Some(_), Some(classify)) => {
                        let n = NeedKernel::new(
                            &mut rec,
                            &compose_base,
                            &compose::gpu::NeedInputs {
                                keys: raster.keys(),
                                positions: pose.positions(),
                                tiles: classify.classes().skin,
                            },
                        )?;
                        kernel.set_needed_segments(Some(n.needed()))?;
                        // The irradiance only where the diffusion of those segments reads
                        // it, and the environment only at the corners of its triangles
                        // (the skin's triangles come first in the frame's mesh, as in the
                        // skin's own).
                        kernel.set_reach(Some(vertices.as_ref().map(|v| ReachMarks {
                            bitmap: v.covered(),
                            first: 0,
                        })))?;
                        Some(n)
                    }
                    _ => None,
                };
                // The diffusion is grey per light: the lights' mean irradiance drives it.
                let lights = cfg
                    .lights
                    .iter()
                    .zip(&lights_toward)
                    .map(|(l, t)| SssLight::Directional {
                        toward: *t,
                        e: (l.irradiance[0] + l.irradiance[1] + l.irradiance[2]) / 3.0,
                    })
                    .collect();
                Some(Skin {
                    kernel,
                    geo: geo.clone(),
                    lights,
                    need,
                })
            }
            None => None,
        };
        let btf_frame = BtfFrame {
            camera: BtfCamera::Perspective(camera.eye),
            // The BTF's values are radiance under irradiance pi: rgb 1 is irradiance pi.
            lights: cfg
                .lights
                .iter()
                .zip(&lights_toward)
                .map(|(l, t)| Light {
                    direction: *t,
                    rgb: l.irradiance.map(|c| c / std::f32::consts::PI),
                })
                .collect(),
        };
        btf_frame.check()?;
        // The cloth under the environment: each BTF's light basis, fitted to the lobes'
        // lighting, and the lobes' tables (once per character, BTF and lobe set).
        let t_basis = Instant::now();
        let bases = btfs
            .iter()
            .map(|b| match &lobes {
                Some(l) => crate::kernels::btf::basis::BasisData::new(b, l).map(|mut d| {
                    d.pixel_lobes =
                        crate::kernels::btf::basis::brightest_lobes(l, cfg.cloth_pixel_lobes);
                    Some(d)
                }),
                None => Ok(None),
            })
            .collect::<Result<Vec<_>>>()?;
        if bases.iter().any(Option::is_some) {
            setup.ms_cloth_basis = t_basis.elapsed().as_secs_f64() * 1e3;
            setup.cloth_basis_captured = bases
                .iter()
                .flatten()
                .map(|b| b.captured)
                .fold(f64::INFINITY, f64::min);
            progress(&format!(
                "cloth light basis: rank {}, at least {:.2}% of each lit BTF's energy ({:.0} ms)",
                crate::kernels::btf::basis::RANK,
                100.0 * setup.cloth_basis_captured,
                setup.ms_cloth_basis
            ));
        }
        // The direction maps (one set for every BTF), kept on the host for the twins.
        let cloth_maps = if btfs.is_empty() {
            None
        } else {
            Some(Maps::build(&Triangulation::new()?, CLOTH_MAP_RES)?)
        };
        // One result for every BTF's passes: each writes its own parts' pixels.
        let cloth_result = match &cloth_maps {
            Some(_) => {
                let r = crate::gpu::Buffer::new(
                    ctx,
                    "cloth radiance",
                    crate::gpu::BufferDesc::storage(cfg.size[0] as u64 * cfg.size[1] as u64 * 16),
                )?;
                rec.fill_buffer(&r, 0)?;
                Some(r)
            }
            None => None,
        };
        let mut cloth = Vec::with_capacity(btfs.len());
        // The parts whose light factors `btf env vertices` computes per vertex: with a
        // vertex list, over its subset of these parts' vertices on covered triangles.
        let mut light_parts = 0u32;
        for (((source, part_mask), btf), basis) in groups.into_iter().zip(btfs).zip(bases) {
            let (Some(maps), Some(result)) = (&cloth_maps, &cloth_result) else {
                break;
            };
            let unused = GBuffer::tile([1, 1]);
            let inputs = BtfInputs::new(&btf, maps, &unused, cfg.cloth_texture);
            let l = ctx.limits();
            let bprep = BtfPrepared::for_gpu_gbuffer(
                &inputs,
                cfg.size,
                l.max_image_dimension_2d,
                l.max_image_array_layers,
            )?;
            // Shaded over the rasteriser's tile list (only where the character is, or was
            // last frame); every frame records `btf shade` after `raster`.
            let tiles = raster.tiles().ok_or_else(|| {
                Error::InvalidArgument("the character's rasteriser has no tile list".into())
            })?;
            let mut k = BtfKernel::on_gbuffer_tiles_into(
                &mut rec,
                &bprep,
                raster.gbuffer(),
                tiles,
                result,
                part_mask,
            )?;
            if let (Some(e), Some(data)) = (&env, &basis) {
                use crate::kernels::btf::gpu::{BasisVisibility, EnvBasisInputs};
                // The light factors per vertex of these parts' triangles, interpolated per
                // pixel (the environment is smooth over a triangle; its visibility was
                // per vertex already).
                let part_verts = part_vertices(&mesh.triangles, &parts, part_mask);
                let visibility = if !cfg.cloth_light_per_vertex(data.lobe_count) {
                    BasisVisibility::PerVertex {
                        keys: raster.keys(),
                        positions: pose.positions(),
                        triangles: raster.triangles(),
                        visibility: e.visibility(),
                    }
                } else {
                    BasisVisibility::PerVertexLight {
                        keys: raster.keys(),
                        positions: pose.positions(),
                        triangles: raster.triangles(),
                        visibility: e.visibility(),
                        normals: pose.normals(),
                        tangents: pose.tangents(),
                        vertices: &part_verts,
                        listed: vertices.as_ref().map(VertexListKernel::subset_list),
                    }
                };
                if let BasisVisibility::PerVertexLight { .. } = visibility {
                    light_parts |= part_mask;
                }
                k.add_env_basis(
                    &mut rec,
                    Some(raster.gbuffer()),
                    EnvBasisInputs {
                        lobes: e.lobes(),
                        data,
                        visibility,
                        part_mask,
                    },
                )?;
            }
            cloth.push(ClothGroup {
                source,
                part_mask,
                btf,
                basis,
                kernel: k,
            });
        }
        if let Some(list) = &mut vertices
            && light_parts != 0
        {
            list.set_subset(
                &mut rec,
                &part_vertices(&mesh.triangles, &parts, light_parts),
            )?;
        }
        let cprep = compose_base.with_surfaces(surfaces)?;
        let compose = ComposeKernel::new(
            &mut rec,
            &cprep,
            &compose::gpu::Inputs {
                gbuffer: raster.gbuffer(),
                keys: raster.keys(),
                positions: pose.positions(),
                diffuse: sss.as_ref().map(|s| s.kernel.diffuse()),
                cloth: cloth_result.as_ref(),
                lobes: env.as_ref().map(|e| (e.lobes(), e.lobe_count() as u32)),
                lobe_visibility: env.as_ref().map(|e| e.visibility()),
                background: cfg.background,
                tiles: raster.tiles().filter(|_| cfg.cull),
                classes: classify.as_ref().map(TileClassKernel::classes),
            },
        )?;
        rec.submit_and_wait()?;
        setup.ms_upload = t.elapsed().as_secs_f64() * 1e3;
        Ok(CharacterFrame {
            character,
            parts,
            anim,
            camera,
            cfg: cfg.clone(),
            pose,
            ao,
            raster,
            classify,
            vertices,
            env,
            sss,
            cloth,
            cloth_result,
            cloth_maps,
            btf_frame,
            compose,
            compose_prep: cprep,
            setup,
        })
    }

    /// Every pass of a frame, in recording order, with its declared uses.
    pub fn passes(&self) -> Vec<crate::kernels::PassInfo> {
        let mut v = Vec::new();
        v.extend(self.pose.passes());
        v.extend(self.ao.passes());
        v.extend(self.raster.passes());
        if let Some(c) = &self.classify {
            v.extend(c.passes());
        }
        // As `record`: the skin's passes before the lights come before the vertex list.
        let skin = self.sss.as_ref().map(|s| {
            let mut all = s.kernel.passes();
            let back = all.split_off(s.kernel.front_passes());
            (s, all, back)
        });
        if let Some((s, front, _)) = &skin {
            if let Some(n) = &s.need {
                v.extend(n.passes());
            }
            v.extend(front.iter().cloned());
        }
        if let Some(l) = &self.vertices {
            v.extend(l.passes());
        }
        if let Some(e) = &self.env {
            v.extend(e.passes());
        }
        if let Some((_, _, back)) = skin {
            v.extend(back);
        }
        for g in &self.cloth {
            v.extend(g.kernel.passes());
        }
        v.extend(self.compose.passes());
        v
    }

    /// [`CharacterFrame::passes`] with the passes of one label joined (in the place of the
    /// first; their uses one after another): a frame with several cloth BTFs records `btf
    /// shade` and `btf env basis` once per BTF, and [`Timings::get`] sums a label's passes.
    pub fn passes_by_name(&self) -> Vec<crate::kernels::PassInfo> {
        let mut out: Vec<crate::kernels::PassInfo> = Vec::new();
        for p in self.passes() {
            match out.iter_mut().find(|q| q.name == p.name) {
                Some(q) => q.uses.extend(p.uses),
                None => out.push(p),
            }
        }
        out
    }

    /// The animation played.
    pub fn animation(&self) -> &Animation {
        &self.character.animations[self.anim]
    }

    /// The configuration the frame was built from (with the exposure of
    /// [`CharacterFrame::set_exposure`]).
    pub fn config(&self) -> &FrameConfig {
        &self.cfg
    }

    /// Sets the exposure of the frames recorded from now on (at first
    /// [`FrameConfig::exposure`]), e.g. a renderer's eye adaptation; frames already recorded
    /// keep theirs. Must be finite and > 0.
    pub fn set_exposure(&mut self, exposure: f32) -> Result<()> {
        if !(exposure.is_finite() && exposure > 0.0) {
            return Err(Error::InvalidArgument(format!(
                "exposure {exposure} must be finite and > 0"
            )));
        }
        self.cfg.exposure = exposure;
        Ok(())
    }

    /// The skinning matrices at `time` seconds (wrapped into the animation).
    pub fn matrices(&self, time: f32) -> Vec<glam::Mat4> {
        looped_matrices(&self.character, self.anim, time)
    }

    /// The compose pass's parameters for a frame.
    pub fn params(&self) -> FrameParams {
        FrameParams {
            camera: self.camera,
            lights: self
                .btf_frame
                .lights
                .iter()
                .zip(&self.cfg.lights)
                .map(|(l, c)| Light {
                    direction: l.direction,
                    rgb: c.irradiance,
                })
                .collect(),
            exposure: self.cfg.exposure,
            specular: self.cfg.specular,
        }
    }

    /// Records one frame into `rec`: every kernel's passes in order, barriers from their
    /// declared accesses. The skinning matrices are evaluated here (host work).
    pub fn record(&self, rec: &mut Recorder, input: &FrameInput) -> Result<()> {
        if !input.time.is_finite() || !input.env_rotation.is_finite() {
            return Err(Error::InvalidArgument(format!(
                "frame input {input:?} is not finite"
            )));
        }
        let m = self.matrices(input.time);
        self.pose.record(rec, &m)?;
        Kernel::record(&self.ao, rec, &m)?;
        self.raster.record(rec, &self.camera)?;
        if let Some(c) = &self.classify {
            c.record(rec, &())?;
        }
        // The skin's geometry and reach come before the vertex list: the reach marks the
        // skin triangles whose vertices the environment's passes shade.
        if let Some(s) = &self.sss {
            if let Some(n) = &s.need {
                n.record(rec, &self.camera)?;
            }
            s.kernel.record_front(rec)?;
        }
        if let Some(v) = &self.vertices {
            v.record(rec, &())?;
        }
        if let Some(e) = &self.env {
            e.record(rec, &input.env_rotation)?;
        }
        if let Some(s) = &self.sss {
            s.kernel.record_back(rec, &s.lights[..])?;
        }
        for g in &self.cloth {
            g.kernel.record(rec, &self.btf_frame)?;
        }
        self.compose.record(rec, &self.params())
    }

    /// Records the readback of the frame's images.
    pub fn read_back(&self, rec: &mut Recorder) -> Result<compose::gpu::ComposeReadback> {
        self.compose.read_back(rec)
    }

    /// The frame's images, once the submission holding the readback is complete.
    pub fn collect(&self, rb: &compose::gpu::ComposeReadback) -> Result<ComposeOutput> {
        self.compose.collect(rb)
    }

    /// Records the readback of what the compose pass read and wrote (tests and tools: the
    /// frame itself reads back only its images).
    pub fn read_back_stages(&self, rec: &mut Recorder) -> Result<StageReadback> {
        let g = self.raster.gbuffer();
        Ok(StageReadback {
            gbuffer: rec.read_back_image(g, crate::gpu::ImageRegion::whole(g.desc()))?,
            keys: rec.read_back(self.raster.keys())?,
            positions: rec.read_back(self.pose.positions())?,
            normals: rec.read_back(self.pose.normals())?,
            tangents: rec.read_back(self.pose.tangents())?,
            ao: self
                .ao
                .occlusion()
                .then(|| rec.read_back(self.ao.visibility()))
                .transpose()?,
            diffuse: match &self.sss {
                Some(s) => Some(rec.read_back(s.kernel.diffuse())?),
                None => None,
            },
            needed: match self.sss.as_ref().and_then(|s| s.need.as_ref()) {
                Some(n) => Some(rec.read_back(n.needed())?),
                None => None,
            },
            reach: match self.sss.as_ref().filter(|s| s.need.is_some()) {
                Some(s) => Some(s.kernel.read_back_reach(rec)?),
                None => None,
            },
            vertices: match &self.vertices {
                Some(v) => Some(Kernel::read_back(v, rec)?),
                None => None,
            },
            classes: match (&self.classify, self.raster.tiles()) {
                (Some(c), Some(t)) => Some((rec.read_back(t)?, c.read_back(rec)?)),
                _ => None,
            },
            cloth: match &self.cloth_result {
                Some(r) => Some(rec.read_back(r)?),
                None => None,
            },
            lobes: match &self.env {
                Some(e) => Some((
                    rec.read_back(e.lobes())?,
                    rec.read_back(e.visibility())?,
                    rec.read_back(e.irradiance())?,
                )),
                None => None,
            },
            images: self.compose.read_back(rec)?,
        })
    }

    /// The stages' outputs, once the submission holding the readback is complete.
    pub fn collect_stages(&self, rb: &StageReadback) -> Result<Stages> {
        let pixels = self.cfg.size[0] as usize * self.cfg.size[1] as usize;
        Ok(Stages {
            gbuffer: rb.gbuffer.to_vec()?,
            keys: rb.keys.to_vec()?,
            positions: rb.positions.to_vec()?,
            normals: rb.normals.to_vec()?,
            tangents: rb.tangents.to_vec()?,
            ao: rb.ao.as_ref().map(|r| r.to_vec()).transpose()?,
            diffuse: match &rb.diffuse {
                Some(r) => r.to_vec()?,
                None => vec![[0.0; 4]; 8],
            },
            needed: match &rb.needed {
                Some(r) => r.to_vec()?,
                None => Vec::new(),
            },
            reach: match (&self.sss, &rb.reach) {
                (Some(s), Some(r)) => Some(s.kernel.reach_segments(r)?),
                _ => None,
            },
            vertices: match (&self.vertices, &rb.vertices) {
                (Some(k), Some(r)) => Some(k.collect(r)?),
                _ => None,
            },
            tile_classes: match (&self.classify, &rb.classes) {
                // The list: head (length, 1, 1, covered), then `length` entries.
                (Some(k), Some((t, c))) => {
                    let words: Vec<u32> = t.to_vec()?;
                    let n = words.first().copied().unwrap_or(0) as usize;
                    let mut tiles =
                        crate::kernels::list_entries(&words, n, "raster tiles")?.to_vec();
                    tiles.sort_unstable();
                    Some((tiles, k.collect(c)?))
                }
                _ => None,
            },
            cloth: match &rb.cloth {
                Some(r) => r.to_vec()?,
                None => vec![[0.0; 4]; pixels],
            },
            lobes: match &rb.lobes {
                Some((l, _, _)) => l.to_vec()?,
                None => Vec::new(),
            },
            lobe_visibility: match &rb.lobes {
                Some((_, v, _)) => v.to_vec()?,
                None => Vec::new(),
            },
            env_irradiance: match &rb.lobes {
                Some((_, _, e)) => e.to_vec()?,
                None => Vec::new(),
            },
            output: self.compose.collect(&rb.images)?,
        })
    }

    /// The compose pass's CPU twin on the stages the GPU computed: (linear radiance, RGBA8).
    pub fn compose_twin(&self, params: &FrameParams, st: &Stages) -> (Vec<[f32; 4]>, Vec<u32>) {
        let (env, vis) = match &self.env {
            Some(e) => (
                compose::Environment::Lobes(e.lobe_count() as u32, self.cfg.background),
                true,
            ),
            None => (compose::Environment::None(self.cfg.background), false),
        };
        compose::cpu::shade(&self.compose_prep, params, env, vis, &st.host_inputs())
    }

    /// Pass `compose need`'s CPU twin on the stages the GPU computed (the keys and posed
    /// positions): the bitmap of the atlas segments the compose pass reads, or None when the
    /// frame diffuses every segment (no skin or no environment).
    pub fn needed_twin(&self, st: &Stages) -> Option<Vec<u32>> {
        self.sss.as_ref()?.need.as_ref()?;
        Some(compose::cpu::needed_segments(
            &self.compose_prep,
            &self.camera,
            &st.host_inputs(),
        ))
    }

    /// Pass `compose classify`'s CPU twin on the stages the GPU computed (the keys and the
    /// rasteriser's tile list): (the tiles without a skin pixel, those with one), sorted, or
    /// None when the frame does not split its tiles (no culling or no skin).
    pub fn tile_classes_twin(&self, st: &Stages) -> Option<(Vec<u32>, Vec<u32>)> {
        let (tiles, _) = st.tile_classes.as_ref()?;
        Some(compose::cpu::tile_classes(
            &self.compose_prep,
            &st.keys,
            tiles,
        ))
    }

    /// The cloth's BTFs: per BTF, where it came from, its parts (bit p: part p) and, when
    /// the frame lights cloth by an environment, its light basis and lobe tables.
    pub fn cloth_btfs(
        &self,
    ) -> Vec<(
        &BtfSource,
        u32,
        Option<&crate::kernels::btf::basis::BasisData>,
    )> {
        self.cloth
            .iter()
            .map(|g| (&g.source, g.part_mask, g.basis.as_ref()))
            .collect()
    }

    /// The cloth's directional lights and camera as `btf shade` takes them (radiance units:
    /// the BTF holds radiance under irradiance pi).
    pub fn btf_frame(&self) -> &BtfFrame {
        &self.btf_frame
    }

    /// The G-buffer of `st` as the BTF twins take it (pixel-major).
    pub fn gbuffer_of(&self, st: &Stages) -> GBuffer {
        let n = st.keys.len();
        GBuffer {
            width: self.cfg.size[0],
            height: self.cfg.size[1],
            texels: (0..n)
                .flat_map(|k| (0..3).map(move |l| st.gbuffer[l * n + k]))
                .collect(),
        }
    }

    /// The cloth stage's CPU twins on the stages the GPU computed (None without cloth): each
    /// BTF's twins over its own parts' pixels.
    pub fn cloth_twins(&self, st: &Stages) -> Result<Option<ClothTwins>> {
        use crate::kernels::btf::basis::{Visibility, barycentrics};
        use crate::kernels::btf::pack::Sampled;
        let Some(maps) = &self.cloth_maps else {
            return Ok(None);
        };
        let gb = self.gbuffer_of(st);
        let n = st.keys.len();
        let part_of = |k: usize| {
            let tag = gb.texels[3 * k][3];
            (tag.abs() >= 0.5).then(|| tag.abs() as u32 - 1)
        };
        let in_mask =
            |k: usize, mask: u32| part_of(k).is_some_and(|p| p < 32 && mask & (1 << p) != 0);
        let mut tw = ClothTwins {
            part_mask: self.cfg.cloth_part_mask(),
            direct: vec![[0.0; 4]; n],
            direct_ambiguous: vec![false; n],
            env: crate::kernels::btf::basis::Shaded {
                radiance: vec![[0.0; 4]; n],
                ambiguous: vec![false; n],
                scale: vec![0.0; n],
            },
            quadrature: None,
        };
        let camera = &self.btf_frame.camera;
        let tri: Vec<u32> = st.keys.iter().map(|&k| key_triangle(k)).collect();
        let triangles = self.raster_triangles();
        for g in &self.cloth {
            let sampled = Sampled::of(&g.btf, self.cfg.cloth_texture);
            let packed = sampled.packed(g.btf.size);
            let (direct, direct_ambiguous) =
                crate::kernels::btf::cpu::shade(&packed, maps, &gb, &self.btf_frame);
            for k in (0..n).filter(|&k| in_mask(k, g.part_mask)) {
                tw.direct[k] = direct[k];
                tw.direct_ambiguous[k] = direct_ambiguous[k];
            }
            let Some(basis) = &g.basis else {
                continue;
            };
            let visibility = if !self.cfg.cloth_light_per_vertex(basis.lobe_count) {
                Visibility::PerVertex {
                    triangle: &tri,
                    positions: &st.positions,
                    triangles: &triangles,
                    visibility: &st.lobe_visibility,
                }
            } else {
                Visibility::PerVertexLight {
                    triangle: &tri,
                    positions: &st.positions,
                    triangles: &triangles,
                    visibility: &st.lobe_visibility,
                    normals: &st.normals,
                    tangents: &st.tangents,
                }
            };
            let env = basis.shade(maps, &gb, camera, &st.lobes, visibility, g.part_mask);
            // The exact pass's per-pixel visibility: the same interpolation.
            let j = st.lobes.len() / 2;
            let mut vis = vec![0f32; n * j];
            let mut group_gb = gb.clone();
            for k in 0..n {
                if !in_mask(k, g.part_mask) {
                    group_gb.texels[3 * k][3] = 0.0;
                    continue;
                }
                let t = triangles[tri[k] as usize];
                let p = |i: u32| Vec3::from_slice(&st.positions[i as usize][..3]);
                let gk = gb.texels[3 * k];
                let w = barycentrics(Vec3::new(gk[0], gk[1], gk[2]), p(t[0]), p(t[1]), p(t[2]));
                for jj in 0..j {
                    vis[k * j + jj] = (0..3)
                        .map(|c| w[c] * st.lobe_visibility[t[c] as usize * j + jj])
                        .sum();
                }
            }
            // The BTF's own quadrature reads its texels at 8-bit sRGB whatever format `btf
            // shade` packs them in: the basis was fitted to the BTF, not to its encoding
            // (blocks add their own error, ~0.3 dB PSNR against the ray-cast truth).
            let (sampled8, packed8);
            let texels = if self.cfg.cloth_texture == Texture::Rgba8 {
                &packed
            } else {
                sampled8 = Sampled::of(&g.btf, Texture::Rgba8);
                packed8 = sampled8.packed(g.btf.size);
                &packed8
            };
            let (q, _) = crate::kernels::btf::env::shade(
                texels,
                maps,
                &group_gb,
                camera,
                &st.lobes,
                Some(&vis),
            );
            let quadrature = tw.quadrature.get_or_insert_with(|| vec![[0.0; 4]; n]);
            for k in (0..n).filter(|&k| in_mask(k, g.part_mask)) {
                tw.env.radiance[k] = env.radiance[k];
                tw.env.ambiguous[k] = env.ambiguous[k];
                tw.env.scale[k] = env.scale[k];
                quadrature[k] = q[k];
            }
        }
        Ok(Some(tw))
    }

    /// The cloth stage's errors on `st`: the light basis against the BTF's own quadrature
    /// of the same (fitted, rotated, shadowed) environment, and the GPU against the twins,
    /// over the cloth pixels (None without cloth).
    pub fn cloth_errors(&self, st: &Stages) -> Result<Option<ClothErrors>> {
        let Some(tw) = self.cloth_twins(st)? else {
            return Ok(None);
        };
        let (mut pixels, mut env_l, mut all_l) = (0usize, 0f64, 0f64);
        let (mut bq, mut bq_den, mut gt, mut gt_den) = (0f64, 0f64, 0f64, 0f64);
        for (k, g) in st.cloth.iter().enumerate() {
            let tag = st.gbuffer[k][3];
            let part = tag.abs() as u32;
            if tag.abs() < 0.5 || part > 32 || tw.part_mask & (1 << (part - 1)) == 0 {
                continue;
            }
            pixels += 1;
            for c in 0..3 {
                let e = tw.env.radiance[k][c];
                let want = tw.direct[k][c] + e;
                env_l += e.abs();
                all_l += want.abs();
                gt += (g[c] as f64 - want).powi(2);
                gt_den += want * want;
                if let Some(q) = &tw.quadrature {
                    bq += (e - q[k][c]).powi(2);
                    bq_den += q[k][c] * q[k][c];
                }
            }
        }
        let rel = |n: f64, d: f64| if d > 0.0 { (n / d).sqrt() } else { 0.0 };
        Ok(Some(ClothErrors {
            pixels,
            env_share: if all_l > 0.0 { env_l / all_l } else { 0.0 },
            basis_vs_quadrature: rel(bq, bq_den),
            gpu_vs_twins: rel(gt, gt_den),
        }))
    }

    /// The compose pass's colour of each part (skin then cloth; empty under
    /// [`Materials::Measured`]).
    pub fn surfaces(&self) -> &[compose::pack::Surface] {
        &self.compose_prep.surfaces
    }

    /// The raster's triangles as uploaded: vertex ids and part id.
    pub fn raster_triangles(&self) -> Vec<[u32; 4]> {
        self.character
            .mesh
            .triangles
            .iter()
            .zip(&self.parts)
            .map(|(t, &p)| [t[0], t[1], t[2], p])
            .collect()
    }

    /// The environment's lobes as fitted (before the frame's rotation), when it has one.
    pub fn env_lobes(&self) -> Option<&[crate::geom::sg::Lobe]> {
        self.env.as_ref().map(|e| e.base_lobes())
    }

    /// The skin's texture-space geometry (rest pose), when the character has skin.
    pub fn skin_geometry(&self) -> Option<&TexGeometry> {
        self.sss.as_ref().map(|s| &s.geo)
    }

    /// The skin's diffusion kernel and its lights, when the character has skin.
    pub fn skin_kernel(&self) -> Option<(&SssKernel, &[SssLight])> {
        self.sss.as_ref().map(|s| (&s.kernel, &s.lights[..]))
    }

    /// Device memory of every kernel.
    pub fn memory_bytes(&self) -> u64 {
        let mut b = self.pose.memory().used_bytes
            + Kernel::memory(&self.ao).used_bytes
            + self.raster.memory().used_bytes
            + self.classify.as_ref().map_or(0, |c| c.memory().used_bytes)
            + self.compose.memory().used_bytes;
        if let Some(s) = &self.sss {
            b += s.kernel.memory().used_bytes;
            if let Some(n) = &s.need {
                b += n.memory().used_bytes;
            }
        }
        for g in &self.cloth {
            b += g.kernel.memory().used_bytes;
        }
        // Each BTF kernel counts the shared result; it is there once.
        if let Some(r) = &self.cloth_result {
            b -= self.cloth.len().saturating_sub(1) as u64 * r.size();
        }
        if let Some(e) = &self.env {
            b += e.memory().used_bytes;
        }
        if let Some(l) = &self.vertices {
            b += l.memory().used_bytes;
        }
        b
    }
}

/// Readbacks of [`CharacterFrame::read_back_stages`].
pub struct StageReadback {
    gbuffer: crate::gpu::Readback,
    keys: crate::gpu::Readback,
    positions: crate::gpu::Readback,
    normals: crate::gpu::Readback,
    tangents: crate::gpu::Readback,
    ao: Option<crate::gpu::Readback>,
    diffuse: Option<crate::gpu::Readback>,
    needed: Option<crate::gpu::Readback>,
    reach: Option<crate::gpu::Readback>,
    vertices: Option<crate::kernels::raster::vertices::VertexListReadback>,
    /// The rasteriser's tile list and pass `compose classify`'s split of it.
    classes: Option<(crate::gpu::Readback, compose::gpu::TileClassReadback)>,
    cloth: Option<crate::gpu::Readback>,
    lobes: Option<(
        crate::gpu::Readback,
        crate::gpu::Readback,
        crate::gpu::Readback,
    )>,
    images: compose::gpu::ComposeReadback,
}

/// What a frame's stages computed, read back.
#[derive(Clone, Debug)]
pub struct Stages {
    /// The G-buffer, layer-major.
    pub gbuffer: Vec<[f32; 4]>,
    /// The rasteriser's keys.
    pub keys: Vec<u64>,
    /// Posed positions and normals.
    pub positions: Vec<[f32; 4]>,
    pub normals: Vec<[f32; 4]>,
    /// Posed tangents (handedness in w).
    pub tangents: Vec<[f32; 4]>,
    /// AO's visibility per vertex; None when the frame does not compute it
    /// ([`FrameConfig::ao_visibility`]).
    pub ao: Option<Vec<f32>>,
    /// The skin's diffusion per atlas texel: this frame's in the segments `needed` marks
    /// (every texel when it is empty), what the texel last held elsewhere.
    pub diffuse: Vec<[f32; 4]>,
    /// Pass `compose need`'s bitmap of the atlas segments diffused this frame
    /// (`kernels::sss::pack::needed_segment` numbers its bits); empty when the diffusion
    /// covers every segment (no environment).
    pub needed: Vec<u32>,
    /// The atlas segments (x / 8 | y << 16, in no set order) whose irradiance the skin's
    /// reach computed this frame ([`SssKernel::set_reach`]), or None when it computes every
    /// segment's (no needed segments).
    pub reach: Option<Vec<u32>>,
    /// The vertices the environment's passes shaded this frame (sorted), or None when they
    /// shade every vertex; the environment's outputs at the others are an older frame's.
    pub vertices: Option<Vec<u32>>,
    /// With culling and skin: the rasteriser's listed tiles this frame (entries `tx | ty <<
    /// 16`, sorted) and pass `compose classify`'s split of them.
    pub tile_classes: Option<(Vec<u32>, compose::gpu::TileClassOutput)>,
    /// The cloth's radiance per pixel.
    pub cloth: Vec<[f32; 4]>,
    /// The rotated environment lobes (two vec4 each) and the per-vertex, per-lobe
    /// visibility; empty without an environment.
    pub lobes: Vec<[f32; 4]>,
    pub lobe_visibility: Vec<f32>,
    /// The shadowed environment irradiance per vertex (rgb, 0); empty without one.
    pub env_irradiance: Vec<[f32; 4]>,
    /// The frame's images.
    pub output: ComposeOutput,
}

impl Stages {
    /// What the compose pass read, as its CPU twins take it.
    pub fn host_inputs(&self) -> compose::cpu::HostInputs<'_> {
        compose::cpu::HostInputs {
            gbuffer: &self.gbuffer,
            keys: &self.keys,
            positions: &self.positions,
            diffuse: &self.diffuse,
            cloth: &self.cloth,
            lobes: &self.lobes,
            lobe_visibility: &self.lobe_visibility,
        }
    }
}

/// One finished frame from [`run`].
pub struct Finished {
    /// Index of the frame's input.
    pub index: usize,
    /// The images.
    pub output: ComposeOutput,
    /// GPU times of every pass.
    pub timings: Timings,
    /// Host ms spent recording and submitting the frame (not waiting).
    pub host_ms: f64,
}

/// Runs `inputs` with up to `in_flight` frames submitted at once, handing each finished
/// frame to `on_frame` in order.
pub fn run(
    ctx: &Context,
    frame: &CharacterFrame,
    inputs: &[FrameInput],
    in_flight: usize,
    mut on_frame: impl FnMut(Finished) -> Result<()>,
) -> Result<()> {
    let in_flight = in_flight.max(1);
    let mut pending = std::collections::VecDeque::new();
    let mut finish = |p: (
        usize,
        crate::gpu::Submission,
        compose::gpu::ComposeReadback,
        f64,
    )| {
        let (index, sub, rb, host_ms) = p;
        let timings = sub.wait()?;
        let output = frame.collect(&rb)?;
        on_frame(Finished {
            index,
            output,
            timings,
            host_ms,
        })
    };
    for (i, input) in inputs.iter().enumerate() {
        let t = Instant::now();
        let mut rec = ctx.recorder(&format!("character frame {i}"))?;
        frame.record(&mut rec, input)?;
        let rb = frame.read_back(&mut rec)?;
        let sub = rec.submit()?;
        let host = t.elapsed().as_secs_f64() * 1e3;
        pending.push_back((i, sub, rb, host));
        if pending.len() >= in_flight
            && let Some(p) = pending.pop_front()
        {
            finish(p)?;
        }
    }
    while let Some(p) = pending.pop_front() {
        finish(p)?;
    }
    Ok(())
}

/// The vertices of the triangles whose part is in `part_mask` (bit p: part p; part ids are
/// below 32, [`FrameConfig::check`]), sorted, once each.
fn part_vertices(triangles: &[[u32; 3]], parts: &[u32], part_mask: u32) -> Vec<u32> {
    let mut v: Vec<u32> = triangles
        .iter()
        .zip(parts)
        .filter(|&(_, &p)| p < 32 && part_mask & (1 << p) != 0)
        .flat_map(|(t, _)| *t)
        .collect();
    v.sort_unstable();
    v.dedup();
    v
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::kernels::btf::cloth::Pattern;

    /// Each cloth part gets its own BTF and tile scale where it has one, the frame's
    /// otherwise; a part that is not cloth, a part named twice and a bad scale are refused.
    #[test]
    fn skin_parts_resolve_per_part_and_refuse_bad_entries() {
        let part = |p: &str, m: Material| SkinPart {
            part: p.into(),
            material: m,
        };
        let cfg = FrameConfig {
            skin: vec!["Head".into(), "Hands".into(), "Ears".into()],
            skin_parts: vec![part("Hands", Material::SKIN2)],
            ..FrameConfig::default()
        };
        assert_eq!(
            cfg.skin_materials().unwrap(),
            [Material::SKIN1, Material::SKIN2, Material::SKIN1]
        );
        let custom = parse_skin_material("0.01,0.1,0.3 / 1,1.2,1.4/1.4").unwrap();
        assert_eq!(custom.sigma_a, [0.01, 0.1, 0.3]);
        assert_eq!(custom.sigma_s_prime, [1.0, 1.2, 1.4]);
        assert_eq!(custom.eta, 1.4);
        assert_eq!(parse_skin_material("skin2").unwrap(), Material::SKIN2);
        for (s, want) in [
            ("marble", "unknown material 'marble'"),
            ("0.01,0.1/1,1,1", "sigma_a has 2 values, not 3"),
            ("0.01,0.1,x/1,1,1", "sigma_a: 'x' is not a number"),
            ("0.01,0.1,0.3/1,1,1/1/2", "4 '/'-separated fields"),
            ("0.01,0.1,0.3/1,1,1/q", "eta 'q' is not a number"),
            ("0.01,0.1,0/1,1,1", "skin material '0.01,0.1,0/1,1,1'"),
        ] {
            let e = parse_skin_material(s).unwrap_err().to_string();
            assert!(e.contains(want), "{s}: {e}");
        }
        let nine: Vec<SkinPart> = (0..9)
            .map(|i| {
                part(
                    &format!("P{i}"),
                    Material::custom([0.01 + i as f64 * 0.01, 0.1, 0.3], [1.0; 3], 1.3).unwrap(),
                )
            })
            .collect();
        for (skin, parts, want) in [
            (
                vec!["Head"],
                vec![part("Torso", Material::SKIN2)],
                "skin part 'Torso' has a scattering material but is not one of the skin parts",
            ),
            (
                vec!["Head"],
                vec![part("Head", Material::SKIN2), part("Head", Material::SKIN1)],
                "'Head' is given its scattering material twice",
            ),
            (
                (0..9)
                    .map(|i| ["P0", "P1", "P2", "P3", "P4", "P5", "P6", "P7", "P8"][i])
                    .collect(),
                nine,
                "9 distinct skin materials; the skin takes at most 8",
            ),
        ] {
            let cfg = FrameConfig {
                skin: skin.into_iter().map(String::from).collect(),
                skin_parts: parts,
                ..FrameConfig::default()
            };
            let e = cfg.check().unwrap_err().to_string();
            assert!(e.contains(want), "{e}");
        }
    }

    #[test]
    fn cloth_parts_resolve_per_part_and_refuse_bad_entries() {
        let part = |p: &str, btf: Option<BtfSource>, t: Option<f32>| ClothPart {
            part: p.into(),
            btf,
            tile_scale: t,
        };
        let cfg = FrameConfig {
            cloth_parts: vec![part(
                "Legs",
                Some(BtfSource::Synthesized(Pattern::Rib)),
                Some(9.0),
            )],
            ..FrameConfig::default()
        };
        let weave = BtfSource::Synthesized(Pattern::Weave);
        assert_eq!(
            cfg.cloth_materials().unwrap(),
            [(weave, 20.0), (BtfSource::Synthesized(Pattern::Rib), 9.0)]
        );
        let with_dir = FrameConfig {
            btf: Some("measured/denim".into()),
            cloth_parts: vec![part("Torso", None, Some(4.0))],
            ..FrameConfig::default()
        };
        let dir = BtfSource::Directory("measured/denim".into());
        assert_eq!(
            with_dir.cloth_materials().unwrap(),
            [(dir.clone(), 4.0), (dir, 20.0)]
        );
        for (bad, want) in [
            (
                vec![part("Head", None, Some(2.0))],
                "'Head' has a BTF or tile scale but is not",
            ),
            (
                vec![part("Legs", None, Some(2.0)), part("Legs", None, None)],
                "'Legs' is given its BTF or tile scale twice",
            ),
            (
                vec![part("Torso", None, Some(f32::NAN))],
                "tile scale NaN must be > 0",
            ),
            (
                vec![part("Torso", None, Some(0.0))],
                "tile scale 0 must be > 0",
            ),
        ] {
            let cfg = FrameConfig {
                cloth_parts: bad,
                ..FrameConfig::default()
            };
            let e = cfg.check().unwrap_err().to_string();
            assert!(e.contains(want), "{e}");
        }
        assert_eq!(
            BtfSource::parse("knit"),
            BtfSource::Synthesized(Pattern::Knit)
        );
        assert_eq!(
            BtfSource::parse("out/btf"),
            BtfSource::Directory("out/btf".into())
        );
    }
}
