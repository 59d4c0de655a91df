//! Compute pipelines whose set layouts and push-constant ranges come from reflection, and
//! bind groups that check every resource against the shader's interface and declare how each
//! binding is accessed (from the reflected `readonly` qualifiers, overridable).

use super::context::{Context, Shared};
use super::image::{Image, ImageInner, Sampler, SamplerInner, Subresources, ViewDesc};
use super::lifetime::{Retired, Stamp, Used};
use super::memory::{Buffer, BufferInner};
use super::shader::{BindingInfo, DescriptorKind, SampledType, Shader};
use super::sync::{AccessSet, AccessType};
use crate::error::{Error, Result, VkResultExt};
use ash::vk;
use std::collections::BTreeMap;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};

/// An image (through a view) given for a binding.
#[derive(Clone, Copy, Debug)]
pub struct ImageRef<'a> {
    /// The image bound.
    pub image: &'a Image,
    /// The view of it the binding sees (by default every subresource, its own format).
    pub view: ViewDesc,
}

impl<'a> ImageRef<'a> {
    /// The default view of `image`: every subresource, its own format.
    pub fn new(image: &'a Image) -> Self {
        ImageRef {
            image,
            view: ViewDesc::default(),
        }
    }

    /// Binds the view `view` describes instead.
    pub fn view(mut self, view: ViewDesc) -> Self {
        self.view = view;
        self
    }
}

impl<'a> From<&'a Image> for ImageRef<'a> {
    fn from(image: &'a Image) -> Self {
        ImageRef::new(image)
    }
}

/// A resource given for one binding.
#[derive(Clone, Debug)]
pub enum Resource<'a> {
    /// A whole storage or uniform buffer.
    Buffer(&'a Buffer),
    /// Part of a buffer: `size` bytes from `offset`.
    BufferRange {
        /// The buffer.
        buffer: &'a Buffer,
        /// Byte offset of the range (a multiple of the binding kind's offset alignment).
        offset: u64,
        /// Bytes in the range.
        size: u64,
    },
    /// A storage image (`image2D`...; GENERAL layout when dispatched).
    StorageImage(ImageRef<'a>),
    /// A sampled image without sampler (`texture2D`...; SHADER_READ_ONLY_OPTIMAL).
    Texture(ImageRef<'a>),
    /// A sampled image with its sampler (`sampler2D`...; SHADER_READ_ONLY_OPTIMAL).
    Sampled(ImageRef<'a>, &'a Sampler),
    /// A sampler alone (`sampler`).
    Sampler(&'a Sampler),
    /// The elements of a descriptor array, in order (as many as the shader declares).
    Array(Vec<Resource<'a>>),
}

impl<'a> Resource<'a> {
    /// The default view of `image` as a storage image.
    pub fn storage_image(image: &'a Image) -> Self {
        Resource::StorageImage(image.into())
    }

    /// The default view of `image` as a sampled image without sampler.
    pub fn texture(image: &'a Image) -> Self {
        Resource::Texture(image.into())
    }

    /// The default view of `image` with `sampler`, for a combined image sampler.
    pub fn sampled(image: &'a Image, sampler: &'a Sampler) -> Self {
        Resource::Sampled(image.into(), sampler)
    }

    fn describe(&self) -> String {
        match self {
            Resource::Buffer(b) => format!("buffer '{}'", b.name()),
            Resource::BufferRange { buffer, .. } => format!("range of buffer '{}'", buffer.name()),
            Resource::StorageImage(i) => format!("storage image '{}'", i.image.name()),
            Resource::Texture(i) => format!("texture '{}'", i.image.name()),
            Resource::Sampled(i, _) => format!("sampled image '{}'", i.image.name()),
            Resource::Sampler(s) => format!("sampler '{}'", s.name()),
            Resource::Array(v) => format!("array of {} resources", v.len()),
        }
    }
}

static PIPELINE_IDS: AtomicU64 = AtomicU64::new(1);

pub(crate) struct PipelineInner {
    shared: Arc<Shared>,
    id: u64,
    name: String,
    bindings: Vec<BindingInfo>,
    push_constant_size: u32,
    local_size: [u32; 3],
    set_layouts: Vec<vk::DescriptorSetLayout>,
    layout: vk::PipelineLayout,
    raw: vk::Pipeline,
    stamp: Stamp,
}

impl Used for PipelineInner {
    fn stamp(&self, value: u64) {
        self.stamp.raise(value);
    }
}

impl Drop for PipelineInner {
    fn drop(&mut self) {
        let mut items = vec![
            Retired::Pipeline(self.raw),
            Retired::PipelineLayout(self.layout),
        ];
        items.extend(self.set_layouts.iter().map(|&l| Retired::SetLayout(l)));
        self.shared.retire(self.stamp.get(), items);
    }
}

/// A compute pipeline and its layout (the owning handle; recordings keep it alive).
pub struct ComputePipeline {
    inner: Arc<PipelineInner>,
}

impl std::fmt::Debug for ComputePipeline {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ComputePipeline")
            .field("name", &self.inner.name)
            .field("local_size", &self.inner.local_size)
            .finish()
    }
}

/// Resolves specialization constants given by name to (id, value), checking every name.
fn resolve_constants(shader: &Shader, constants: &[(&str, u32)]) -> Result<Vec<(u32, u32)>> {
    constants
        .iter()
        .map(|(name, value)| {
            let c = shader
                .spec_constants
                .iter()
                .find(|c| c.name == *name)
                .ok_or_else(|| Error::Interface {
                    pipeline: shader.name.clone(),
                    reason: format!(
                        "no specialization constant named '{name}' (it has: {})",
                        shader
                            .spec_constants
                            .iter()
                            .map(|c| format!("'{}' (id {})", c.name, c.id))
                            .collect::<Vec<_>>()
                            .join(", ")
                    ),
                })?;
            Ok((c.id, *value))
        })
        .collect()
}

/// The workgroup size the resolved constants give, checked against the device limits, and
/// the push-constant and descriptor-set counts checked too.
fn checked_local_size(
    shared: &Shared,
    shader: &Shader,
    resolved: &[(u32, u32)],
) -> Result<[u32; 3]> {
    let limits = &shared.info.limits;
    let limit_err = |what: &str, requested: u64, limit_name, limit: u64| Error::Limit {
        what: format!("{what} of shader '{}'", shader.name),
        requested,
        limit_name,
        limit,
    };
    let mut local_size = shader.local_size;
    for (axis, spec) in shader.local_size_spec.iter().enumerate() {
        if let Some(&(_, v)) = spec.and_then(|id| resolved.iter().rev().find(|(i, _)| *i == id)) {
            local_size[axis] = v;
        }
    }
    if local_size.contains(&0) {
        return Err(Error::Interface {
            pipeline: shader.name.clone(),
            reason: format!("specialised workgroup size {local_size:?} has a zero dimension"),
        });
    }
    for (axis, (&size, &max)) in local_size
        .iter()
        .zip(&limits.max_compute_work_group_size)
        .enumerate()
    {
        if size > max {
            return Err(limit_err(
                &format!("workgroup size along axis {axis}"),
                size as u64,
                "maxComputeWorkGroupSize",
                max as u64,
            ));
        }
    }
    let invocations: u64 = local_size.iter().map(|&s| s as u64).product();
    if invocations > limits.max_compute_work_group_invocations as u64 {
        return Err(limit_err(
            "invocations per workgroup",
            invocations,
            "maxComputeWorkGroupInvocations",
            limits.max_compute_work_group_invocations as u64,
        ));
    }
    if shader.push_constant_size > limits.max_push_constants_size {
        return Err(limit_err(
            "push-constant bytes",
            shader.push_constant_size as u64,
            "maxPushConstantsSize",
            limits.max_push_constants_size as u64,
        ));
    }
    let n_sets = shader.bindings.iter().map(|b| b.set + 1).max().unwrap_or(0);
    if n_sets > limits.max_bound_descriptor_sets {
        return Err(limit_err(
            "descriptor sets",
            n_sets as u64,
            "maxBoundDescriptorSets",
            limits.max_bound_descriptor_sets as u64,
        ));
    }
    Ok(local_size)
}

impl PipelineInner {
    /// The context that made the pipeline.
    pub(crate) fn shared(&self) -> &Arc<Shared> {
        &self.shared
    }

    /// Creates the set layouts and the pipeline layout.
    fn create_layouts(&mut self) -> Result<()> {
        let device = &self.shared.device;
        let n_sets = self.bindings.iter().map(|b| b.set + 1).max().unwrap_or(0);
        for set in 0..n_sets {
            let layout_bindings: Vec<_> = self
                .bindings
                .iter()
                .filter(|b| b.set == set)
                .map(|b| {
                    vk::DescriptorSetLayoutBinding::default()
                        .binding(b.binding)
                        .descriptor_type(b.kind.vk())
                        .descriptor_count(b.count)
                        .stage_flags(vk::ShaderStageFlags::COMPUTE)
                })
                .collect();
            let info = vk::DescriptorSetLayoutCreateInfo::default().bindings(&layout_bindings);
            // SAFETY: valid device and create info.
            let l = unsafe { device.create_descriptor_set_layout(&info, None) }
                .vk("vkCreateDescriptorSetLayout")?;
            self.set_layouts.push(l);
        }
        let ranges = [vk::PushConstantRange {
            stage_flags: vk::ShaderStageFlags::COMPUTE,
            offset: 0,
            size: self.push_constant_size,
        }];
        let ranges: &[vk::PushConstantRange] = if self.push_constant_size > 0 {
            &ranges
        } else {
            &[]
        };
        let layout_info = vk::PipelineLayoutCreateInfo::default()
            .set_layouts(&self.set_layouts)
            .push_constant_ranges(ranges);
        // SAFETY: valid device and create info.
        self.layout = unsafe { device.create_pipeline_layout(&layout_info, None) }
            .vk("vkCreatePipelineLayout")?;
        Ok(())
    }

    /// Creates the pipeline from the shader with the resolved constants.
    fn create_pipeline(&mut self, shader: &Shader, resolved: &[(u32, u32)]) -> Result<()> {
        let device = &self.shared.device;
        let module_info = vk::ShaderModuleCreateInfo::default().code(&shader.words);
        // SAFETY: the words passed SPIRV-Tools validation in Shader::from_spirv.
        let module = unsafe { device.create_shader_module(&module_info, None) }
            .vk("vkCreateShaderModule")?;
        let entry = std::ffi::CString::new(shader.entry_point.clone()).map_err(|_| Error::Spirv {
            name: shader.name.clone(),
            reason: "entry point name contains NUL".into(),
        });
        let entry = match entry {
            Ok(e) => e,
            Err(e) => {
                // SAFETY: unused module.
                unsafe { device.destroy_shader_module(module, None) };
                return Err(e);
            }
        };
        let mut entries = Vec::with_capacity(resolved.len());
        let mut data: Vec<u8> = Vec::with_capacity(4 * resolved.len());
        for (id, value) in resolved {
            entries.push(vk::SpecializationMapEntry {
                constant_id: *id,
                offset: data.len() as u32,
                size: 4,
            });
            data.extend_from_slice(&value.to_le_bytes());
        }
        let specialization = vk::SpecializationInfo::default()
            .map_entries(&entries)
            .data(&data);
        let mut stage = vk::PipelineShaderStageCreateInfo::default()
            .stage(vk::ShaderStageFlags::COMPUTE)
            .module(module)
            .name(&entry);
        if !entries.is_empty() {
            stage = stage.specialization_info(&specialization);
        }
        let info = [vk::ComputePipelineCreateInfo::default()
            .stage(stage)
            .layout(self.layout)];
        // SAFETY: valid module and layout.
        let created =
            unsafe { device.create_compute_pipelines(vk::PipelineCache::null(), &info, None) };
        // SAFETY: the module is no longer needed once the pipeline exists (or failed).
        unsafe { device.destroy_shader_module(module, None) };
        self.raw = created.map_err(|(_, r)| Error::Vk {
            call: "vkCreateComputePipelines",
            result: r,
        })?[0];
        Ok(())
    }
}

impl ComputePipeline {
    /// Loads SPIR-V bytes (validated and reflected) and builds the pipeline.
    pub fn from_spirv(ctx: &Context, name: &str, spirv: &[u8]) -> Result<ComputePipeline> {
        ComputePipeline::new(ctx, &Shader::from_spirv(name, spirv)?)
    }

    /// Builds the pipeline for a reflected shader, checking workgroup size and push-constant
    /// size against the device limits.
    pub fn new(ctx: &Context, shader: &Shader) -> Result<ComputePipeline> {
        ComputePipeline::specialized(ctx, shader, &[])
    }

    /// As [`ComputePipeline::new`], with specialization constants set by name (32-bit values:
    /// `u32`, `f32::to_bits`, 0/1 for booleans). A name the shader does not declare is an
    /// error; constants not given keep their defaults.
    pub fn specialized(
        ctx: &Context,
        shader: &Shader,
        constants: &[(&str, u32)],
    ) -> Result<ComputePipeline> {
        let shared = &ctx.shared;
        shared.collect();
        let resolved = resolve_constants(shader, constants)?;
        let local_size = checked_local_size(shared, shader, &resolved)?;
        if let Some(b) = shader.bindings.iter().find(|b| b.count == 0) {
            return Err(Error::Interface {
                pipeline: shader.name.clone(),
                reason: format!(
                    "binding '{}' is a runtime-sized array, which vkshade does not bind",
                    b.name
                ),
            });
        }
        // Objects created below are retired by `inner`'s Drop if a later step fails.
        let mut inner = PipelineInner {
            shared: shared.clone(),
            id: PIPELINE_IDS.fetch_add(1, Ordering::Relaxed),
            name: shader.name.clone(),
            bindings: shader.bindings.clone(),
            push_constant_size: shader.push_constant_size,
            local_size,
            set_layouts: Vec::new(),
            layout: vk::PipelineLayout::null(),
            raw: vk::Pipeline::null(),
            stamp: Stamp::default(),
        };
        inner.create_layouts()?;
        inner.create_pipeline(shader, &resolved)?;
        shared.set_name(inner.raw, &shader.name);
        shared.set_name(inner.layout, &format!("{} layout", shader.name));
        Ok(ComputePipeline {
            inner: Arc::new(inner),
        })
    }

    pub(crate) fn keep(&self) -> Arc<PipelineInner> {
        self.inner.clone()
    }

    /// The name given at creation (also its debug-utils name).
    pub fn name(&self) -> &str {
        &self.inner.name
    }

    /// Workgroup size, after specialization constants.
    pub fn local_size(&self) -> [u32; 3] {
        self.inner.local_size
    }

    /// Bytes of push constants the shader declares (what a dispatch must pass).
    pub fn push_constant_size(&self) -> u32 {
        self.inner.push_constant_size
    }

    /// The shader's bindings, sorted by set and binding.
    pub fn bindings(&self) -> &[BindingInfo] {
        &self.inner.bindings
    }

    /// The Vulkan pipeline.
    pub fn raw(&self) -> vk::Pipeline {
        self.inner.raw
    }

    /// The Vulkan pipeline layout (set layouts and push-constant range from reflection).
    pub fn layout(&self) -> vk::PipelineLayout {
        self.inner.layout
    }

    fn interface_err(&self, reason: String) -> Error {
        Error::Interface {
            pipeline: self.inner.name.clone(),
            reason,
        }
    }

    /// Creates descriptor sets holding `resources`, given by the shader's variable names.
    /// Every binding of the shader must be given exactly once, with a resource of the right
    /// kind, usage and size: a buffer range non-empty, inside its buffer and aligned; an
    /// image's view format of the numeric class the shader reads (float, signed or unsigned
    /// integer); a format the device filters linearly wherever the shader samples it with a
    /// sampler bound with linear filtering. Anything else is an error naming the binding.
    /// Accesses are the defaults of [`default_access`].
    pub fn bind(&self, resources: &[(&str, Resource<'_>)]) -> Result<BindGroup> {
        self.bind_declared(resources, &[])
    }

    /// As [`ComputePipeline::bind`], declaring the access of some bindings instead of the
    /// reflected default (e.g. a storage buffer the shader only writes:
    /// `AccessType::ComputeShaderWrite`).
    pub fn bind_declared(
        &self,
        resources: &[(&str, Resource<'_>)],
        accesses: &[(&str, AccessSet)],
    ) -> Result<BindGroup> {
        let mut by_binding: BTreeMap<(u32, u32), (&BindingInfo, Resource<'_>)> = BTreeMap::new();
        for (name, res) in resources {
            let info = self.binding_named(name)?;
            let res = self.resolve_views(info, res)?;
            self.check_resource(info, &res)?;
            if by_binding
                .insert((info.set, info.binding), (info, res))
                .is_some()
            {
                return Err(self.interface_err(format!("binding '{name}' given twice")));
            }
        }
        let missing: Vec<_> = self
            .inner
            .bindings
            .iter()
            .filter(|b| !by_binding.contains_key(&(b.set, b.binding)))
            .map(|b| {
                format!(
                    "'{}' ({:?}, set {} binding {})",
                    b.name, b.kind, b.set, b.binding
                )
            })
            .collect();
        if !missing.is_empty() {
            return Err(self.interface_err(format!("no resource given for {}", missing.join(", "))));
        }
        self.check_separate_samplers(&by_binding)?;
        let mut overrides = BTreeMap::new();
        for (name, access) in accesses {
            let info = self.binding_named(name)?;
            self.check_override(info, *access)?;
            overrides.insert((info.set, info.binding), *access);
        }
        BindGroup::new(self, &by_binding, &overrides)
    }

    /// As [`ComputePipeline::bind_declared`], taking each reflected binding's resource from
    /// `lookup` by the binding's name (e.g. a kernel's table of its resources by the names
    /// the shaders use); a name `lookup` does not know is an error naming the binding.
    pub fn bind_from<'a>(
        &self,
        lookup: impl Fn(&str) -> Option<Resource<'a>>,
        accesses: &[(&str, AccessSet)],
    ) -> Result<BindGroup> {
        let resources = (self.inner.bindings.iter())
            .map(|b| match lookup(&b.name) {
                Some(res) => Ok((b.name.as_str(), res)),
                None => Err(self.interface_err(format!(
                    "no resource for binding '{}' ({:?}, set {} binding {})",
                    b.name, b.kind, b.set, b.binding
                ))),
            })
            .collect::<Result<Vec<_>>>()?;
        self.bind_declared(&resources, accesses)
    }

    /// An override must be an access the descriptor allows: non-empty, the same image
    /// layout as the default (the descriptor is written with it), and no writes through a
    /// sampled image or a uniform buffer.
    fn check_override(&self, info: &BindingInfo, access: AccessSet) -> Result<()> {
        let default = default_access(info);
        let writes = access.iter().any(AccessType::is_write);
        let read_only_kind = matches!(
            info.kind,
            DescriptorKind::UniformBuffer
                | DescriptorKind::SampledImage
                | DescriptorKind::CombinedImageSampler
        );
        if default.is_empty() || access.is_empty() || (writes && read_only_kind) {
            return Err(self.interface_err(format!(
                "binding '{}' ({:?}) cannot be declared as {access:?}",
                info.name, info.kind
            )));
        }
        if info.view_type.is_some() && access.layout() != default.layout() {
            return Err(self.interface_err(format!(
                "binding '{}' is bound in layout {:?}; {access:?} needs {:?}",
                info.name,
                default.layout(),
                access.layout()
            )));
        }
        Ok(())
    }

    /// The resource with each image view's type set from the shader's image type (`image2D`
    /// gets a 2D view); a view type given that differs from it is an error.
    fn resolve_views<'a>(&self, info: &BindingInfo, res: &Resource<'a>) -> Result<Resource<'a>> {
        let fix = |img: &ImageRef<'a>| -> Result<ImageRef<'a>> {
            let mut r = *img;
            match (r.view.view_type, info.view_type) {
                (None, t) => r.view.view_type = t,
                (Some(given), Some(needed)) if given != needed => {
                    return Err(self.interface_err(format!(
                        "binding '{}' needs a {needed:?} view; image '{}' was given as {given:?}",
                        info.name,
                        img.image.name()
                    )));
                }
                _ => {}
            }
            Ok(r)
        };
        Ok(match res {
            Resource::StorageImage(i) => Resource::StorageImage(fix(i)?),
            Resource::Texture(i) => Resource::Texture(fix(i)?),
            Resource::Sampled(i, s) => Resource::Sampled(fix(i)?, s),
            Resource::Array(items) => Resource::Array(
                items
                    .iter()
                    .map(|r| self.resolve_views(info, r))
                    .collect::<Result<_>>()?,
            ),
            other => other.clone(),
        })
    }

    fn binding_named(&self, name: &str) -> Result<&BindingInfo> {
        self.inner
            .bindings
            .iter()
            .find(|b| b.name == name)
            .ok_or_else(|| {
                self.interface_err(format!(
                    "the shader has no binding named '{name}' (it has: {})",
                    self.binding_list()
                ))
            })
    }

    fn binding_list(&self) -> String {
        self.inner
            .bindings
            .iter()
            .map(|b| format!("'{}' {:?}", b.name, b.kind))
            .collect::<Vec<_>>()
            .join(", ")
    }

    fn check_resource(&self, info: &BindingInfo, res: &Resource<'_>) -> Result<()> {
        if let Resource::Array(items) = res {
            if info.count == 1 {
                return Err(self.interface_err(format!(
                    "binding '{}' is a single {:?}, not an array",
                    info.name, info.kind
                )));
            }
            if items.len() != info.count as usize {
                return Err(self.interface_err(format!(
                    "binding '{}' is an array of {}, given {} resources",
                    info.name,
                    info.count,
                    items.len()
                )));
            }
            return items.iter().try_for_each(|r| self.check_single(info, r));
        }
        if info.count != 1 {
            return Err(self.interface_err(format!(
                "binding '{}' is an array of {}: give Resource::Array",
                info.name, info.count
            )));
        }
        self.check_single(info, res)
    }

    fn check_single(&self, info: &BindingInfo, res: &Resource<'_>) -> Result<()> {
        let mismatch = || {
            self.interface_err(format!(
                "binding '{}' is a {:?} but was given a {}",
                info.name,
                info.kind,
                res.describe()
            ))
        };
        let needs_usage = |img: &ImageRef<'_>, usage: vk::ImageUsageFlags| {
            if !img.image.desc().usage.contains(usage) {
                return Err(self.interface_err(format!(
                    "image '{}' for binding '{}' lacks {usage:?} usage",
                    img.image.name(),
                    info.name
                )));
            }
            img.image.keep().view(&img.view, usage).map(|_| ())
        };
        match (info.kind, res) {
            (
                DescriptorKind::StorageBuffer | DescriptorKind::UniformBuffer,
                Resource::Buffer(_) | Resource::BufferRange { .. },
            ) => self.check_buffer(info, res),
            (DescriptorKind::StorageImage, Resource::StorageImage(img)) => {
                needs_usage(img, vk::ImageUsageFlags::STORAGE)?;
                self.check_sampled_type(info, img)
            }
            (DescriptorKind::SampledImage, Resource::Texture(img)) => {
                needs_usage(img, vk::ImageUsageFlags::SAMPLED)?;
                self.check_sampled_type(info, img)
            }
            (DescriptorKind::CombinedImageSampler, Resource::Sampled(img, sampler)) => {
                needs_usage(img, vk::ImageUsageFlags::SAMPLED)?;
                self.check_filter(info, img, sampler, None)?;
                self.check_sampled_type(info, img)
            }
            (DescriptorKind::Sampler, Resource::Sampler(_)) => Ok(()),
            _ => Err(mismatch()),
        }
    }

    /// The view's format must have the numeric class the shader reads (a float `texture3D`
    /// cannot read an `R32_UINT` image, nor a `utexture3D` a float one:
    /// VUID-vkCmdDispatch-format-07753).
    fn check_sampled_type(&self, info: &BindingInfo, img: &ImageRef<'_>) -> Result<()> {
        let format = img.view.format.unwrap_or(img.image.desc().format);
        let (Some(reads), Some(has)) = (info.sampled_type, SampledType::of_format(format)) else {
            return Ok(());
        };
        if reads == has {
            return Ok(());
        }
        let what = |t: SampledType| match t {
            SampledType::Float => ("float", "without prefix (texture*, image*, sampler*)"),
            SampledType::SignedInt => {
                ("signed integer", "with `i` (itexture*, iimage*, isampler*)")
            }
            SampledType::UnsignedInt => (
                "unsigned integer",
                "with `u` (utexture*, uimage*, usampler*)",
            ),
        };
        Err(self.interface_err(format!(
            "binding {} reads {} texels, but image '{}' is bound with format {format:?}, whose \
             texels are {}: declare the image type {} or bind a {} format",
            binding_label(info),
            what(reads).0,
            img.image.name(),
            what(has).0,
            what(has).1,
            what(reads).0
        )))
    }

    /// A sampler that filters linearly (LINEAR magnification or minification filter, or
    /// LINEAR mipmap mode) needs a view format the device filters linearly
    /// (VUID-vkCmdDispatch-magFilter-04553, VUID-vkCmdDispatch-mipmapMode-04770).
    /// `sampler_binding` is the separate sampler's binding, `None` for a combined one.
    fn check_filter(
        &self,
        info: &BindingInfo,
        img: &ImageRef<'_>,
        sampler: &Sampler,
        sampler_binding: Option<&BindingInfo>,
    ) -> Result<()> {
        let format = img.view.format.unwrap_or(img.image.desc().format);
        let needed = vk::FormatFeatureFlags::SAMPLED_IMAGE_FILTER_LINEAR;
        if !sampler.desc().filters_linearly()
            || self.inner.shared.format_features(format).contains(needed)
        {
            return Ok(());
        }
        Err(self.interface_err(format!(
            "binding {}: sampler '{}'{} filters linearly, but image '{}' has format \
             {format:?}, which device '{}' cannot filter linearly ({needed:?}); use a nearest \
             sampler or another format",
            binding_label(info),
            sampler.name(),
            sampler_binding
                .map(|s| format!(" (binding {})", binding_label(s)))
                .unwrap_or_default(),
            img.image.name(),
            self.inner.shared.info.name
        )))
    }

    /// The filter check of combined image samplers for separate textures: each texture
    /// against every sampler bound to a binding the shader combines it with.
    fn check_separate_samplers(
        &self,
        bound: &BTreeMap<(u32, u32), (&BindingInfo, Resource<'_>)>,
    ) -> Result<()> {
        for (info, res) in bound.values() {
            for key in &info.sampled_with {
                let Some((sampler_info, samplers)) = bound.get(key) else {
                    continue;
                };
                for s in elements(samplers) {
                    let Resource::Sampler(sampler) = s else {
                        continue;
                    };
                    for t in elements(res) {
                        if let Resource::Texture(img) = t {
                            self.check_filter(info, img, sampler, Some(sampler_info))?;
                        }
                    }
                }
            }
        }
        Ok(())
    }

    fn check_buffer(&self, info: &BindingInfo, res: &Resource<'_>) -> Result<()> {
        let (buffer, offset, size) = match *res {
            Resource::Buffer(b) => (b, 0, b.size()),
            Resource::BufferRange {
                buffer,
                offset,
                size,
            } => (buffer, offset, size),
            _ => unreachable!("only called for buffers"),
        };
        let storage = info.kind == DescriptorKind::StorageBuffer;
        let usage = if storage {
            vk::BufferUsageFlags::STORAGE_BUFFER
        } else {
            vk::BufferUsageFlags::UNIFORM_BUFFER
        };
        if !buffer.usage().contains(usage) {
            return Err(self.interface_err(format!(
                "buffer '{}' for binding '{}' lacks usage {usage:?}",
                buffer.name(),
                info.name
            )));
        }
        // VUID-VkDescriptorBufferInfo-range-00341 (a range of 0), -offset-00340 (an offset
        // at or past the end), -range-00342 (a range past the end).
        if size == 0 {
            return Err(self.interface_err(format!(
                "binding {}: the range of buffer '{}' at offset {offset} is empty (size 0)",
                binding_label(info),
                buffer.name()
            )));
        }
        if offset >= buffer.size()
            || offset
                .checked_add(size)
                .is_none_or(|end| end > buffer.size())
        {
            return Err(self.interface_err(format!(
                "binding {}: range {offset}+{size} is outside buffer '{}' of {} bytes",
                binding_label(info),
                buffer.name(),
                buffer.size()
            )));
        }
        let limits = &self.inner.shared.info.limits;
        let (align, align_name) = if storage {
            (
                limits.min_storage_buffer_offset_alignment,
                "minStorageBufferOffsetAlignment",
            )
        } else {
            (
                limits.min_uniform_buffer_offset_alignment,
                "minUniformBufferOffsetAlignment",
            )
        };
        if offset % align.max(1) != 0 {
            return Err(self.interface_err(format!(
                "binding {}: offset {offset} into buffer '{}' is not a multiple of \
                 {align_name} = {align}",
                binding_label(info),
                buffer.name()
            )));
        }
        if size < info.min_size {
            return Err(self.interface_err(format!(
                "binding '{}' needs at least {} bytes, buffer '{}' gives {size}",
                info.name,
                info.min_size,
                buffer.name()
            )));
        }
        Ok(())
    }
}

/// A binding as errors name it: `'name' (set S binding B)`.
fn binding_label(info: &BindingInfo) -> String {
    format!(
        "'{}' (set {} binding {})",
        info.name, info.set, info.binding
    )
}

/// The access a binding gets unless declared otherwise: `readonly` storage buffers and
/// images are read (`ComputeShaderReadOther`), other storage bindings read and written,
/// uniform buffers `ComputeShaderReadUniformBuffer`, sampled images
/// `ComputeShaderReadSampledImage`; samplers have none.
pub fn default_access(info: &BindingInfo) -> AccessSet {
    use AccessType as A;
    match info.kind {
        DescriptorKind::StorageBuffer | DescriptorKind::StorageImage if info.read_only => {
            A::ComputeShaderReadOther.into()
        }
        DescriptorKind::StorageBuffer | DescriptorKind::StorageImage => {
            A::ComputeShaderReadOther | A::ComputeShaderWrite
        }
        DescriptorKind::UniformBuffer => A::ComputeShaderReadUniformBuffer.into(),
        DescriptorKind::SampledImage | DescriptorKind::CombinedImageSampler => {
            A::ComputeShaderReadSampledImage.into()
        }
        DescriptorKind::Sampler => AccessSet::EMPTY,
    }
}

/// What one binding of a bind group touches and how.
#[derive(Clone)]
pub(crate) enum Target {
    Buffer(Arc<BufferInner>),
    Image(Arc<ImageInner>, Subresources),
}

/// A declared use: binding name, resource, access.
#[derive(Clone)]
pub(crate) struct BoundUse {
    pub binding: String,
    pub target: Target,
    pub access: AccessSet,
}

/// How one binding of a bind group is accessed (for inspection, e.g. by a render graph).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct DeclaredUse {
    /// The binding's name in the shader.
    pub binding: String,
    /// The name of the buffer or image bound to it.
    pub resource: String,
    /// How the dispatch accesses it.
    pub access: AccessSet,
    /// Bytes of the bound range (a buffer range's size; for an image, its allocation's
    /// share of the bound layers): what the dispatch can touch at most.
    pub bytes: u64,
}

pub(crate) struct BindGroupInner {
    shared: Arc<Shared>,
    pipeline_id: u64,
    pool: vk::DescriptorPool,
    sets: Vec<vk::DescriptorSet>,
    pub(crate) uses: Vec<BoundUse>,
    resources: Vec<Arc<dyn Used>>,
    stamp: Stamp,
}

impl BindGroupInner {
    /// The context of the pipeline the group was made for.
    pub(crate) fn shared(&self) -> &Arc<Shared> {
        &self.shared
    }
}

impl Used for BindGroupInner {
    fn stamp(&self, value: u64) {
        self.stamp.raise(value);
        for r in &self.resources {
            r.stamp(value);
        }
    }

    fn host_visible(&self) -> bool {
        self.resources.iter().any(|r| r.host_visible())
    }
}

impl Drop for BindGroupInner {
    fn drop(&mut self) {
        self.shared
            .retire(self.stamp.get(), [Retired::DescriptorPool(self.pool)]);
    }
}

/// Descriptor sets for one pipeline, in their own pool. It keeps the buffers, images and
/// samplers it refers to alive, and recordings keep it alive until the GPU is done.
pub struct BindGroup {
    inner: Arc<BindGroupInner>,
}

/// Fails unless every resource bound (and sampler) belongs to the pipeline's context.
fn check_contexts(
    pipeline: &ComputePipeline,
    bound: &BTreeMap<(u32, u32), (&BindingInfo, Resource<'_>)>,
) -> Result<()> {
    let p = &pipeline.inner;
    let user = || format!("pipeline '{}'", p.name);
    for (info, res) in bound.values() {
        for r in elements(res) {
            let (owner, what) = match r {
                Resource::Buffer(b) | Resource::BufferRange { buffer: b, .. } => {
                    (b.keep().shared.clone(), format!("buffer '{}'", b.name()))
                }
                Resource::StorageImage(i) | Resource::Texture(i) | Resource::Sampled(i, _) => (
                    i.image.keep().shared.clone(),
                    format!("image '{}'", i.image.name()),
                ),
                Resource::Sampler(s) => {
                    (s.keep().shared.clone(), format!("sampler '{}'", s.name()))
                }
                Resource::Array(_) => continue,
            };
            p.shared
                .check_owner(&owner, || format!("{what} (binding '{}')", info.name), user)?;
            if let Resource::Sampled(_, s) = r {
                p.shared.check_owner(
                    &s.keep().shared,
                    || format!("sampler '{}' (binding '{}')", s.name(), info.name),
                    user,
                )?;
            }
        }
    }
    Ok(())
}

/// Flattens a binding's resource into its elements.
fn elements<'r, 'a>(res: &'r Resource<'a>) -> Vec<&'r Resource<'a>> {
    match res {
        Resource::Array(items) => items.iter().collect(),
        single => vec![single],
    }
}

impl BindGroup {
    fn new(
        pipeline: &ComputePipeline,
        bound: &BTreeMap<(u32, u32), (&BindingInfo, Resource<'_>)>,
        overrides: &BTreeMap<(u32, u32), AccessSet>,
    ) -> Result<BindGroup> {
        let p = &pipeline.inner;
        check_contexts(pipeline, bound)?;
        let device = &p.shared.device;
        let mut counts: BTreeMap<i32, u32> = BTreeMap::new();
        let mut resources: Vec<Arc<dyn Used>> = Vec::new();
        let mut uses = Vec::new();
        for (key, (info, res)) in bound {
            *counts.entry(info.kind.vk().as_raw()).or_default() += info.count;
            let access = overrides
                .get(key)
                .copied()
                .unwrap_or_else(|| default_access(info));
            for r in elements(res) {
                let target = match r {
                    Resource::Buffer(b) | Resource::BufferRange { buffer: b, .. } => {
                        resources.push(b.keep());
                        Some(Target::Buffer(b.keep()))
                    }
                    Resource::StorageImage(i) | Resource::Texture(i) => {
                        resources.push(i.image.keep());
                        let range = i.image.keep().view_range(&i.view);
                        Some(Target::Image(i.image.keep(), range))
                    }
                    Resource::Sampled(i, s) => {
                        resources.push(i.image.keep());
                        resources.push(s.keep() as Arc<SamplerInner>);
                        let range = i.image.keep().view_range(&i.view);
                        Some(Target::Image(i.image.keep(), range))
                    }
                    Resource::Sampler(s) => {
                        resources.push(s.keep());
                        None
                    }
                    Resource::Array(_) => unreachable!("flattened"),
                };
                if let Some(target) = target
                    && !access.is_empty()
                {
                    uses.push(BoundUse {
                        binding: info.name.clone(),
                        target,
                        access,
                    });
                }
            }
        }
        check_overlaps(pipeline, &uses)?;
        let sizes: Vec<_> = counts
            .iter()
            .map(|(&ty, &n)| vk::DescriptorPoolSize {
                ty: vk::DescriptorType::from_raw(ty),
                descriptor_count: n,
            })
            .collect();
        let n_sets = p.set_layouts.len() as u32;
        let mut group = BindGroupInner {
            shared: p.shared.clone(),
            pipeline_id: p.id,
            pool: vk::DescriptorPool::null(),
            sets: Vec::new(),
            uses,
            resources,
            stamp: Stamp::default(),
        };
        if n_sets > 0 {
            let info = vk::DescriptorPoolCreateInfo::default()
                .max_sets(n_sets)
                .pool_sizes(&sizes);
            // SAFETY: valid device and create info.
            group.pool = unsafe { device.create_descriptor_pool(&info, None) }
                .vk("vkCreateDescriptorPool")?;
            super::recycle::Counters::bump(&p.shared.counters.descriptor_pools);
            let alloc = vk::DescriptorSetAllocateInfo::default()
                .descriptor_pool(group.pool)
                .set_layouts(&p.set_layouts);
            // SAFETY: the pool was sized for exactly these sets.
            group.sets = unsafe { device.allocate_descriptor_sets(&alloc) }
                .vk("vkAllocateDescriptorSets")?;
            write_sets(&group, bound)?;
        }
        Ok(BindGroup {
            inner: Arc::new(group),
        })
    }

    /// The descriptor sets, indexed by set number.
    pub fn sets(&self) -> &[vk::DescriptorSet] {
        &self.inner.sets
    }

    /// Whether these sets were made for `pipeline`.
    pub fn is_for(&self, pipeline: &ComputePipeline) -> bool {
        self.inner.pipeline_id == pipeline.inner.id
    }

    /// How each binding is accessed by a dispatch with this group.
    pub fn accesses(&self) -> Vec<DeclaredUse> {
        self.inner
            .uses
            .iter()
            .map(|u| DeclaredUse {
                binding: u.binding.clone(),
                resource: match &u.target {
                    Target::Buffer(b) => b.name.clone(),
                    Target::Image(i, _) => i.name.clone(),
                },
                access: u.access,
                bytes: match &u.target {
                    Target::Buffer(b) => b.alloc_bytes(),
                    Target::Image(i, sub) => {
                        i.alloc_bytes() * sub.layer_count as u64 / i.desc.layers.max(1) as u64
                    }
                },
            })
            .collect()
    }

    pub(crate) fn keep(&self) -> Arc<BindGroupInner> {
        self.inner.clone()
    }
}

/// Two bindings of one group on overlapping subresources of one image must use the same
/// layout (a texture and a storage image of the same mip cannot both be right).
fn check_overlaps(pipeline: &ComputePipeline, uses: &[BoundUse]) -> Result<()> {
    let overlap = |a: &Subresources, b: &Subresources| {
        a.base_mip < b.base_mip + b.mip_count
            && b.base_mip < a.base_mip + a.mip_count
            && a.base_layer < b.base_layer + b.layer_count
            && b.base_layer < a.base_layer + a.layer_count
    };
    for (i, a) in uses.iter().enumerate() {
        for b in &uses[i + 1..] {
            if let (Target::Image(ia, ra), Target::Image(ib, rb)) = (&a.target, &b.target)
                && Arc::ptr_eq(ia, ib)
                && overlap(ra, rb)
                && a.access.layout() != b.access.layout()
            {
                return Err(pipeline.interface_err(format!(
                    "bindings '{}' and '{}' use the same subresources of image '{}' in layouts \
                     {:?} and {:?}; bind different mips or layers, or one binding",
                    a.binding,
                    b.binding,
                    ia.name,
                    a.access.layout(),
                    b.access.layout()
                )));
            }
        }
    }
    Ok(())
}

/// Writes every descriptor of `bound` into the group's sets.
fn write_sets(
    group: &BindGroupInner,
    bound: &BTreeMap<(u32, u32), (&BindingInfo, Resource<'_>)>,
) -> Result<()> {
    let mut buffer_infos: Vec<(&BindingInfo, Vec<vk::DescriptorBufferInfo>)> = Vec::new();
    let mut image_infos: Vec<(&BindingInfo, Vec<vk::DescriptorImageInfo>)> = Vec::new();
    for (info, res) in bound.values() {
        let items = elements(res);
        match info.kind {
            DescriptorKind::StorageBuffer | DescriptorKind::UniformBuffer => {
                let infos = items
                    .iter()
                    .map(|r| match **r {
                        Resource::Buffer(b) => vk::DescriptorBufferInfo {
                            buffer: b.raw(),
                            offset: 0,
                            range: vk::WHOLE_SIZE,
                        },
                        Resource::BufferRange {
                            buffer,
                            offset,
                            size,
                        } => vk::DescriptorBufferInfo {
                            buffer: buffer.raw(),
                            offset,
                            range: size,
                        },
                        _ => unreachable!("checked"),
                    })
                    .collect();
                buffer_infos.push((info, infos));
            }
            _ => {
                let mut infos = Vec::with_capacity(items.len());
                for r in items {
                    let (view, sampler, layout) = match r {
                        Resource::StorageImage(i) => (
                            i.image.keep().view(&i.view, vk::ImageUsageFlags::empty())?,
                            vk::Sampler::null(),
                            vk::ImageLayout::GENERAL,
                        ),
                        Resource::Texture(i) => (
                            i.image.keep().view(&i.view, vk::ImageUsageFlags::empty())?,
                            vk::Sampler::null(),
                            vk::ImageLayout::SHADER_READ_ONLY_OPTIMAL,
                        ),
                        Resource::Sampled(i, s) => (
                            i.image.keep().view(&i.view, vk::ImageUsageFlags::empty())?,
                            s.raw(),
                            vk::ImageLayout::SHADER_READ_ONLY_OPTIMAL,
                        ),
                        Resource::Sampler(s) => {
                            (vk::ImageView::null(), s.raw(), vk::ImageLayout::UNDEFINED)
                        }
                        _ => unreachable!("checked"),
                    };
                    infos.push(vk::DescriptorImageInfo {
                        sampler,
                        image_view: view,
                        image_layout: layout,
                    });
                }
                image_infos.push((info, infos));
            }
        }
    }
    let mut writes = Vec::new();
    for (info, bi) in &buffer_infos {
        writes.push(
            vk::WriteDescriptorSet::default()
                .dst_set(group.sets[info.set as usize])
                .dst_binding(info.binding)
                .descriptor_type(info.kind.vk())
                .buffer_info(bi),
        );
    }
    for (info, ii) in &image_infos {
        writes.push(
            vk::WriteDescriptorSet::default()
                .dst_set(group.sets[info.set as usize])
                .dst_binding(info.binding)
                .descriptor_type(info.kind.vk())
                .image_info(ii),
        );
    }
    // SAFETY: every write targets a set of this group with a checked resource whose views
    // are alive (cached by their images, which the group keeps).
    unsafe { group.shared.device.update_descriptor_sets(&writes, &[]) };
    Ok(())
}

impl std::fmt::Debug for BindGroup {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let uses: Vec<&str> = self.inner.uses.iter().map(|u| u.binding.as_str()).collect();
        f.debug_struct("BindGroup")
            .field("pipeline_id", &self.inner.pipeline_id)
            .field("uses", &uses)
            .finish()
    }
}
