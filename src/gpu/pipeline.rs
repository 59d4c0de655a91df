//! Compute pipelines whose set layouts and push-constant ranges come from reflection, and
//! bind groups that check every resource against the shader's interface.

use super::context::{Context, Shared};
use super::memory::{Buffer, Image, Sampler};
use super::shader::{BindingInfo, DescriptorKind, Shader};
use crate::error::{Error, Result, VkResultExt};
use ash::vk;
use std::collections::BTreeMap;
use std::sync::Arc;

/// A resource given for one binding.
#[derive(Clone, Copy)]
pub enum Resource<'a> {
    /// A whole storage or uniform buffer.
    Buffer(&'a Buffer),
    /// Part of a buffer: `size` bytes from `offset`.
    BufferRange {
        buffer: &'a Buffer,
        offset: u64,
        size: u64,
    },
    /// A storage image (GENERAL layout when dispatched).
    StorageImage(&'a Image),
    /// A sampled image with its sampler (SHADER_READ_ONLY_OPTIMAL when dispatched).
    Sampled(&'a Image, &'a Sampler),
}

impl Resource<'_> {
    fn describe(&self) -> String {
        match self {
            Resource::Buffer(b) => format!("buffer '{}'", b.name()),
            Resource::BufferRange { buffer, .. } => format!("range of buffer '{}'", buffer.name()),
            Resource::StorageImage(i) => format!("storage image '{}'", i.name()),
            Resource::Sampled(i, _) => format!("sampled image '{}'", i.name()),
        }
    }
}

/// A compute pipeline and its layout.
pub struct ComputePipeline {
    shared: Arc<Shared>,
    name: String,
    bindings: Vec<BindingInfo>,
    push_constant_size: u32,
    local_size: [u32; 3],
    set_layouts: Vec<vk::DescriptorSetLayout>,
    layout: vk::PipelineLayout,
    raw: vk::Pipeline,
}

impl std::fmt::Debug for ComputePipeline {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ComputePipeline")
            .field("name", &self.name)
            .field("local_size", &self.local_size)
            .finish()
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
        let limits = &shared.info.limits;
        let limit_err = |what: &str, requested: u64, limit_name, limit: u64| Error::Limit {
            what: format!("{what} of shader '{}'", shader.name),
            requested,
            limit_name,
            limit,
        };
        // Specialization constants by name, checked before anything is created.
        let mut resolved: Vec<(u32, u32)> = Vec::with_capacity(constants.len());
        for (name, value) in constants {
            let Some(c) = shader.spec_constants.iter().find(|c| c.name == *name) else {
                return Err(Error::Interface {
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
                });
            };
            resolved.push((c.id, *value));
        }
        // The workgroup size these constants give.
        let mut local_size = shader.local_size;
        for (axis, spec) in shader.local_size_spec.iter().enumerate() {
            if let Some(&(_, v)) = spec.and_then(|id| resolved.iter().rev().find(|(i, _)| *i == id))
            {
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
        if let Some(b) = shader.bindings.iter().find(|b| b.count != 1) {
            return Err(Error::Interface {
                pipeline: shader.name.clone(),
                reason: format!(
                    "binding '{}' is an array of {}; arrays of descriptors are not supported",
                    b.name, b.count
                ),
            });
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

        let mut pipeline = ComputePipeline {
            shared: shared.clone(),
            name: shader.name.clone(),
            bindings: shader.bindings.clone(),
            push_constant_size: shader.push_constant_size,
            local_size,
            set_layouts: Vec::new(),
            layout: vk::PipelineLayout::null(),
            raw: vk::Pipeline::null(),
        };
        // Objects created below are destroyed by `pipeline`'s Drop if a later step fails.
        for set in 0..n_sets {
            let layout_bindings: Vec<_> = shader
                .bindings
                .iter()
                .filter(|b| b.set == set)
                .map(|b| {
                    vk::DescriptorSetLayoutBinding::default()
                        .binding(b.binding)
                        .descriptor_type(b.kind.vk())
                        .descriptor_count(1)
                        .stage_flags(vk::ShaderStageFlags::COMPUTE)
                })
                .collect();
            let info = vk::DescriptorSetLayoutCreateInfo::default().bindings(&layout_bindings);
            // SAFETY: valid device and create info.
            let l = unsafe { shared.device.create_descriptor_set_layout(&info, None) }
                .vk("vkCreateDescriptorSetLayout")?;
            pipeline.set_layouts.push(l);
        }
        let ranges = [vk::PushConstantRange {
            stage_flags: vk::ShaderStageFlags::COMPUTE,
            offset: 0,
            size: shader.push_constant_size,
        }];
        let ranges: &[vk::PushConstantRange] = if shader.push_constant_size > 0 {
            &ranges
        } else {
            &[]
        };
        let layout_info = vk::PipelineLayoutCreateInfo::default()
            .set_layouts(&pipeline.set_layouts)
            .push_constant_ranges(ranges);
        // SAFETY: valid device and create info.
        pipeline.layout = unsafe { shared.device.create_pipeline_layout(&layout_info, None) }
            .vk("vkCreatePipelineLayout")?;

        let module_info = vk::ShaderModuleCreateInfo::default().code(&shader.words);
        // SAFETY: the words passed SPIRV-Tools validation in Shader::from_spirv.
        let module = unsafe { shared.device.create_shader_module(&module_info, None) }
            .vk("vkCreateShaderModule")?;
        let entry =
            std::ffi::CString::new(shader.entry_point.clone()).map_err(|_| Error::Spirv {
                name: shader.name.clone(),
                reason: "entry point name contains NUL".into(),
            })?;
        let mut entries = Vec::with_capacity(resolved.len());
        let mut data: Vec<u8> = Vec::with_capacity(4 * resolved.len());
        for (id, value) in &resolved {
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
            .layout(pipeline.layout)];
        // SAFETY: valid module and layout.
        let created = unsafe {
            shared
                .device
                .create_compute_pipelines(vk::PipelineCache::null(), &info, None)
        };
        // SAFETY: the module is no longer needed once the pipeline exists (or failed).
        unsafe { shared.device.destroy_shader_module(module, None) };
        pipeline.raw = created.map_err(|(_, r)| Error::Vk {
            call: "vkCreateComputePipelines",
            result: r,
        })?[0];
        shared.set_name(pipeline.raw, &shader.name);
        shared.set_name(pipeline.layout, &format!("{} layout", shader.name));
        Ok(pipeline)
    }

    pub fn name(&self) -> &str {
        &self.name
    }

    pub fn local_size(&self) -> [u32; 3] {
        self.local_size
    }

    pub fn push_constant_size(&self) -> u32 {
        self.push_constant_size
    }

    pub fn bindings(&self) -> &[BindingInfo] {
        &self.bindings
    }

    pub fn raw(&self) -> vk::Pipeline {
        self.raw
    }

    pub fn layout(&self) -> vk::PipelineLayout {
        self.layout
    }

    fn interface_err(&self, reason: String) -> Error {
        Error::Interface {
            pipeline: self.name.clone(),
            reason,
        }
    }

    /// Creates descriptor sets holding `resources`, given by the shader's variable names.
    /// Every binding of the shader must be given exactly once, with a resource of the right
    /// kind, usage and size; anything else is an error naming the binding.
    pub fn bind(&self, resources: &[(&str, Resource<'_>)]) -> Result<BindGroup> {
        let mut by_binding: BTreeMap<(u32, u32), (&BindingInfo, Resource<'_>)> = BTreeMap::new();
        for (name, res) in resources {
            let info = self
                .bindings
                .iter()
                .find(|b| b.name == *name)
                .ok_or_else(|| {
                    self.interface_err(format!(
                        "the shader has no binding named '{name}' (it has: {})",
                        self.binding_list()
                    ))
                })?;
            self.check_resource(info, res)?;
            if by_binding
                .insert((info.set, info.binding), (info, *res))
                .is_some()
            {
                return Err(self.interface_err(format!("binding '{name}' given twice")));
            }
        }
        let missing: Vec<_> = self
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
        BindGroup::new(self, &by_binding)
    }

    fn binding_list(&self) -> String {
        self.bindings
            .iter()
            .map(|b| format!("'{}' {:?}", b.name, b.kind))
            .collect::<Vec<_>>()
            .join(", ")
    }

    fn check_resource(&self, info: &BindingInfo, res: &Resource<'_>) -> Result<()> {
        let mismatch = || {
            self.interface_err(format!(
                "binding '{}' is a {:?} but was given a {}",
                info.name,
                info.kind,
                res.describe()
            ))
        };
        match (info.kind, res) {
            (
                DescriptorKind::StorageBuffer | DescriptorKind::UniformBuffer,
                Resource::Buffer(_) | Resource::BufferRange { .. },
            ) => {
                let (buffer, offset, size) = match *res {
                    Resource::Buffer(b) => (b, 0, b.size()),
                    Resource::BufferRange {
                        buffer,
                        offset,
                        size,
                    } => (buffer, offset, size),
                    _ => unreachable!("matched above"),
                };
                let usage = if info.kind == DescriptorKind::StorageBuffer {
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
                if offset
                    .checked_add(size)
                    .is_none_or(|end| end > buffer.size())
                {
                    return Err(self.interface_err(format!(
                        "range {offset}+{size} is outside buffer '{}' of {} bytes",
                        buffer.name(),
                        buffer.size()
                    )));
                }
                let limits = &self.shared.info.limits;
                let (align, align_name) = if info.kind == DescriptorKind::StorageBuffer {
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
                        "offset {offset} into buffer '{}' is not a multiple of {align_name} = {align}",
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
            (DescriptorKind::StorageImage, Resource::StorageImage(img)) => {
                if !img.desc().usage.contains(vk::ImageUsageFlags::STORAGE) {
                    return Err(self.interface_err(format!(
                        "image '{}' for binding '{}' lacks STORAGE usage",
                        img.name(),
                        info.name
                    )));
                }
                Ok(())
            }
            (DescriptorKind::CombinedImageSampler, Resource::Sampled(img, _)) => {
                if !img.desc().usage.contains(vk::ImageUsageFlags::SAMPLED) {
                    return Err(self.interface_err(format!(
                        "image '{}' for binding '{}' lacks SAMPLED usage",
                        img.name(),
                        info.name
                    )));
                }
                Ok(())
            }
            _ => Err(mismatch()),
        }
    }
}

impl Drop for ComputePipeline {
    fn drop(&mut self) {
        // SAFETY: no pending work uses the pipeline (every submission waits); null handles
        // from a failed construction are ignored by the destroy calls.
        unsafe {
            self.shared.device.destroy_pipeline(self.raw, None);
            self.shared
                .device
                .destroy_pipeline_layout(self.layout, None);
            for &l in &self.set_layouts {
                self.shared.device.destroy_descriptor_set_layout(l, None);
            }
        }
    }
}

/// Descriptor sets for one pipeline, in their own pool. It keeps the buffers, images and
/// samplers it refers to alive, so dropping their handles first is harmless.
pub struct BindGroup {
    shared: Arc<Shared>,
    pipeline: vk::Pipeline,
    pool: vk::DescriptorPool,
    sets: Vec<vk::DescriptorSet>,
    _resources: Vec<Arc<dyn std::any::Any + Send + Sync>>,
}

impl BindGroup {
    fn new(
        pipeline: &ComputePipeline,
        bound: &BTreeMap<(u32, u32), (&BindingInfo, Resource<'_>)>,
    ) -> Result<BindGroup> {
        let device = &pipeline.shared.device;
        let mut counts: BTreeMap<i32, u32> = BTreeMap::new();
        for (info, _) in bound.values() {
            *counts.entry(info.kind.vk().as_raw()).or_default() += 1;
        }
        let sizes: Vec<_> = counts
            .iter()
            .map(|(&ty, &n)| vk::DescriptorPoolSize {
                ty: vk::DescriptorType::from_raw(ty),
                descriptor_count: n,
            })
            .collect();
        let n_sets = pipeline.set_layouts.len() as u32;
        let mut resources: Vec<Arc<dyn std::any::Any + Send + Sync>> = Vec::new();
        for (_, res) in bound.values() {
            match *res {
                Resource::Buffer(b) | Resource::BufferRange { buffer: b, .. } => {
                    resources.push(b.keep())
                }
                Resource::StorageImage(i) => resources.push(i.keep()),
                Resource::Sampled(i, s) => {
                    resources.push(i.keep());
                    resources.push(s.keep());
                }
            }
        }
        let mut group = BindGroup {
            shared: pipeline.shared.clone(),
            pipeline: pipeline.raw,
            pool: vk::DescriptorPool::null(),
            sets: Vec::new(),
            _resources: resources,
        };
        if n_sets == 0 {
            return Ok(group);
        }
        let info = vk::DescriptorPoolCreateInfo::default()
            .max_sets(n_sets)
            .pool_sizes(&sizes);
        // SAFETY: valid device and create info.
        group.pool =
            unsafe { device.create_descriptor_pool(&info, None) }.vk("vkCreateDescriptorPool")?;
        let alloc = vk::DescriptorSetAllocateInfo::default()
            .descriptor_pool(group.pool)
            .set_layouts(&pipeline.set_layouts);
        // SAFETY: the pool was sized for exactly these sets.
        group.sets =
            unsafe { device.allocate_descriptor_sets(&alloc) }.vk("vkAllocateDescriptorSets")?;
        let mut buffer_infos = Vec::new();
        let mut image_infos = Vec::new();
        for (info, res) in bound.values() {
            match *res {
                Resource::Buffer(b) => buffer_infos.push((
                    info,
                    vk::DescriptorBufferInfo {
                        buffer: b.raw(),
                        offset: 0,
                        range: vk::WHOLE_SIZE,
                    },
                )),
                Resource::BufferRange {
                    buffer,
                    offset,
                    size,
                } => buffer_infos.push((
                    info,
                    vk::DescriptorBufferInfo {
                        buffer: buffer.raw(),
                        offset,
                        range: size,
                    },
                )),
                Resource::StorageImage(img) => image_infos.push((
                    info,
                    vk::DescriptorImageInfo {
                        sampler: vk::Sampler::null(),
                        image_view: img.view(),
                        image_layout: vk::ImageLayout::GENERAL,
                    },
                )),
                Resource::Sampled(img, s) => image_infos.push((
                    info,
                    vk::DescriptorImageInfo {
                        sampler: s.raw(),
                        image_view: img.view(),
                        image_layout: vk::ImageLayout::SHADER_READ_ONLY_OPTIMAL,
                    },
                )),
            }
        }
        let mut writes = Vec::new();
        for (info, bi) in &buffer_infos {
            writes.push(
                vk::WriteDescriptorSet::default()
                    .dst_set(group.sets[info.set as usize])
                    .dst_binding(info.binding)
                    .descriptor_type(info.kind.vk())
                    .buffer_info(std::slice::from_ref(bi)),
            );
        }
        for (info, ii) in &image_infos {
            writes.push(
                vk::WriteDescriptorSet::default()
                    .dst_set(group.sets[info.set as usize])
                    .dst_binding(info.binding)
                    .descriptor_type(info.kind.vk())
                    .image_info(std::slice::from_ref(ii)),
            );
        }
        // SAFETY: every write targets a set of this group with a checked resource.
        unsafe { device.update_descriptor_sets(&writes, &[]) };
        Ok(group)
    }

    /// The descriptor sets, indexed by set number.
    pub fn sets(&self) -> &[vk::DescriptorSet] {
        &self.sets
    }

    /// Whether these sets were made for `pipeline`.
    pub fn is_for(&self, pipeline: &ComputePipeline) -> bool {
        self.pipeline == pipeline.raw
    }
}

impl Drop for BindGroup {
    fn drop(&mut self) {
        // SAFETY: not in use by pending work; destroying the pool frees its sets.
        unsafe { self.shared.device.destroy_descriptor_pool(self.pool, None) };
    }
}
