//! Samplers: filtering, addressing and level of detail ([`SamplerDesc`]), checked against
//! the device's limits and features.

use crate::error::{Error, Result, VkResultExt};
use crate::gpu::context::{Context, Shared};
use crate::gpu::lifetime::{Retired, Stamp, Used};
use ash::vk;
use std::sync::Arc;

/// Filtering, addressing and level-of-detail of a sampler.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SamplerDesc {
    /// Filter when magnifying.
    pub mag_filter: vk::Filter,
    /// Filter when minifying.
    pub min_filter: vk::Filter,
    /// Nearest mip level, or linear interpolation between two.
    pub mipmap_mode: vk::SamplerMipmapMode,
    /// Address modes for u, v, w.
    pub address: [vk::SamplerAddressMode; 3],
    /// Colour outside the image for the clamp-to-border address mode.
    pub border: vk::BorderColor,
    /// Added to the computed level of detail (at most `maxSamplerLodBias` in magnitude).
    pub mip_lod_bias: f32,
    /// Lowest level of detail used (clamps the computed one).
    pub min_lod: f32,
    /// `vk::LOD_CLAMP_NONE` for every level.
    pub max_lod: f32,
    /// Maximum anisotropy (needs the `sampler_anisotropy` feature), `None` for off.
    pub anisotropy: Option<f32>,
    /// Unnormalized coordinates (texel units; nearest/linear, clamp, one level).
    pub unnormalized: bool,
}

impl SamplerDesc {
    /// Linear filtering and linear mip interpolation, clamp to edge, every level.
    pub fn linear() -> Self {
        SamplerDesc {
            mag_filter: vk::Filter::LINEAR,
            min_filter: vk::Filter::LINEAR,
            mipmap_mode: vk::SamplerMipmapMode::LINEAR,
            address: [vk::SamplerAddressMode::CLAMP_TO_EDGE; 3],
            border: vk::BorderColor::FLOAT_TRANSPARENT_BLACK,
            mip_lod_bias: 0.0,
            min_lod: 0.0,
            max_lod: vk::LOD_CLAMP_NONE,
            anisotropy: None,
            unnormalized: false,
        }
    }

    /// Nearest filtering and nearest mip, clamp to edge, every level.
    pub fn nearest() -> Self {
        SamplerDesc {
            mag_filter: vk::Filter::NEAREST,
            min_filter: vk::Filter::NEAREST,
            mipmap_mode: vk::SamplerMipmapMode::NEAREST,
            ..Self::linear()
        }
    }

    /// The same address mode on every axis.
    pub fn address(mut self, mode: vk::SamplerAddressMode) -> Self {
        self.address = [mode; 3];
        self
    }

    /// An address mode per axis.
    pub fn address_uvw(
        mut self,
        u: vk::SamplerAddressMode,
        v: vk::SamplerAddressMode,
        w: vk::SamplerAddressMode,
    ) -> Self {
        self.address = [u, v, w];
        self
    }

    /// Sets the border colour.
    pub fn border(mut self, border: vk::BorderColor) -> Self {
        self.border = border;
        self
    }

    /// Clamps the level of detail to `min..=max`.
    pub fn lod(mut self, min: f32, max: f32) -> Self {
        self.min_lod = min;
        self.max_lod = max;
        self
    }

    /// Anisotropic filtering up to `max` (needs the `sampler_anisotropy` feature).
    pub fn anisotropy(mut self, max: f32) -> Self {
        self.anisotropy = Some(max);
        self
    }

    /// Unnormalized (texel) coordinates: level 0 only, nearest mip mode, and the
    /// minification filter set to the magnification filter (as Vulkan requires).
    pub fn unnormalized(mut self) -> Self {
        self.unnormalized = true;
        self.mipmap_mode = vk::SamplerMipmapMode::NEAREST;
        self.min_filter = self.mag_filter;
        self.max_lod = 0.0;
        self
    }

    /// Whether any filter is linear (the image format then needs linear filtering).
    pub fn filters_linearly(&self) -> bool {
        self.mag_filter == vk::Filter::LINEAR
            || self.min_filter == vk::Filter::LINEAR
            || self.mipmap_mode == vk::SamplerMipmapMode::LINEAR
    }

    fn check(&self, ctx: &Context, name: &str) -> Result<()> {
        let bad = |why: String| Err(Error::InvalidArgument(format!("sampler '{name}': {why}")));
        if self
            .min_lod
            .partial_cmp(&self.max_lod)
            .is_none_or(|o| o.is_gt())
            || !self.mip_lod_bias.is_finite()
        {
            return bad(format!(
                "LOD range {}..{} / bias {} is invalid",
                self.min_lod, self.max_lod, self.mip_lod_bias
            ));
        }
        let limits = ctx.limits();
        if self.mip_lod_bias.abs() > limits.max_sampler_lod_bias {
            return bad(format!(
                "LOD bias {} exceeds maxSamplerLodBias = {}",
                self.mip_lod_bias, limits.max_sampler_lod_bias
            ));
        }
        if let Some(a) = self.anisotropy {
            if !ctx.features().sampler_anisotropy {
                return Err(Error::Unsupported {
                    device: ctx.info().name.clone(),
                    what: format!(
                        "anisotropic filtering for sampler '{name}': request the \
                         sampler_anisotropy feature in ContextDesc::features"
                    ),
                });
            }
            if !(1.0..=limits.max_sampler_anisotropy).contains(&a) {
                return bad(format!(
                    "anisotropy {a} is outside 1..=maxSamplerAnisotropy ({})",
                    limits.max_sampler_anisotropy
                ));
            }
        }
        if self.unnormalized {
            let clamp = self.address.iter().take(2).all(|m| {
                matches!(
                    *m,
                    vk::SamplerAddressMode::CLAMP_TO_EDGE | vk::SamplerAddressMode::CLAMP_TO_BORDER
                )
            });
            if self.min_filter != self.mag_filter
                || self.mipmap_mode != vk::SamplerMipmapMode::NEAREST
                || self.min_lod != 0.0
                || self.max_lod != 0.0
                || self.anisotropy.is_some()
                || !clamp
            {
                return bad(
                    "unnormalized coordinates need equal min/mag filters, nearest mips, LOD 0, \
                     clamp addressing and no anisotropy"
                        .into(),
                );
            }
        }
        Ok(())
    }
}

pub(crate) struct SamplerInner {
    pub(crate) shared: Arc<Shared>,
    pub(crate) raw: vk::Sampler,
    pub(crate) desc: SamplerDesc,
    pub(crate) name: String,
    stamp: Stamp,
}

impl Used for SamplerInner {
    fn stamp(&self, value: u64) {
        self.stamp.raise(value);
    }
}

impl Drop for SamplerInner {
    fn drop(&mut self) {
        self.shared
            .retire(self.stamp.get(), [Retired::Sampler(self.raw)]);
    }
}

/// A sampler object (the owning handle).
pub struct Sampler {
    inner: Arc<SamplerInner>,
}

impl std::fmt::Debug for Sampler {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Sampler")
            .field("name", &self.inner.name)
            .field("desc", &self.inner.desc)
            .finish()
    }
}

impl Sampler {
    /// Creates a sampler, checking LOD range, bias, anisotropy and the unnormalized-coordinate
    /// rules against the device.
    pub fn new(ctx: &Context, name: &str, desc: SamplerDesc) -> Result<Sampler> {
        desc.check(ctx, name)?;
        let mut info = vk::SamplerCreateInfo::default()
            .mag_filter(desc.mag_filter)
            .min_filter(desc.min_filter)
            .mipmap_mode(desc.mipmap_mode)
            .address_mode_u(desc.address[0])
            .address_mode_v(desc.address[1])
            .address_mode_w(desc.address[2])
            .border_color(desc.border)
            .mip_lod_bias(desc.mip_lod_bias)
            .min_lod(desc.min_lod)
            .max_lod(desc.max_lod)
            .unnormalized_coordinates(desc.unnormalized);
        if let Some(a) = desc.anisotropy {
            info = info.anisotropy_enable(true).max_anisotropy(a);
        }
        // SAFETY: valid device and create info (checked above).
        let raw = unsafe { ctx.shared.device.create_sampler(&info, None) }.vk("vkCreateSampler")?;
        ctx.shared.set_name(raw, name);
        Ok(Sampler {
            inner: Arc::new(SamplerInner {
                shared: ctx.shared.clone(),
                raw,
                desc,
                name: name.to_string(),
                stamp: Stamp::default(),
            }),
        })
    }

    /// The Vulkan sampler.
    pub fn raw(&self) -> vk::Sampler {
        self.inner.raw
    }

    /// What the sampler does.
    pub fn desc(&self) -> &SamplerDesc {
        &self.inner.desc
    }

    /// The name given at creation (also its debug-utils name).
    pub fn name(&self) -> &str {
        &self.inner.name
    }

    pub(crate) fn keep(&self) -> Arc<SamplerInner> {
        self.inner.clone()
    }
}
