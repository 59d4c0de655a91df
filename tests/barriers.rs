//! The access-type -> barrier mapping, checked against the Khronos synchronization examples
//! (github.com/KhronosGroup/Vulkan-Docs/wiki/Synchronization-Examples), in their
//! synchronization2 form. Where the examples use the generic SHADER_READ/SHADER_WRITE bits for
//! storage and uniform buffers, vkshade uses the precise synchronization2 bits (STORAGE /
//! UNIFORM), which the spec defines as subsets of them; sampled images keep SHADER_READ.

use ash::vk;
use vkshade::gpu::sync::{
    BarrierMasks, barrier_masks, buffer_barrier, image_barrier, memory_barrier,
};
use vkshade::gpu::{AccessSet, AccessType as A};

use vk::AccessFlags2 as F;
use vk::ImageLayout as L;
use vk::PipelineStageFlags2 as S;

fn masks(prev: impl Into<AccessSet>, next: impl Into<AccessSet>) -> BarrierMasks {
    barrier_masks(prev.into(), next.into(), false)
}

fn expect(m: BarrierMasks, src: (S, F), dst: (S, F)) {
    assert_eq!(
        m,
        BarrierMasks {
            src_stages: src.0,
            src_access: src.1,
            dst_stages: dst.0,
            dst_access: dst.1
        }
    );
}

fn range() -> vk::ImageSubresourceRange {
    vk::ImageSubresourceRange {
        aspect_mask: vk::ImageAspectFlags::COLOR,
        base_mip_level: 0,
        level_count: 1,
        base_array_layer: 0,
        layer_count: 1,
    }
}

#[test]
fn compute_write_storage_buffer_then_compute_read() {
    // "Dispatch writes into a storage buffer. Dispatch reads from that storage buffer."
    expect(
        masks(A::ComputeShaderWrite, A::ComputeShaderReadOther),
        (S::COMPUTE_SHADER, F::SHADER_STORAGE_WRITE),
        (S::COMPUTE_SHADER, F::SHADER_STORAGE_READ),
    );
}

#[test]
fn compute_read_then_compute_write_is_execution_only() {
    // "Dispatch reads from a storage buffer. Dispatch writes to that storage buffer."
    // Write-after-read: an execution dependency, no memory barrier.
    expect(
        masks(A::ComputeShaderReadOther, A::ComputeShaderWrite),
        (S::COMPUTE_SHADER, F::NONE),
        (S::COMPUTE_SHADER, F::NONE),
    );
}

#[test]
fn compute_write_then_compute_write_orders_both_writes() {
    expect(
        masks(A::ComputeShaderWrite, A::ComputeShaderWrite),
        (S::COMPUTE_SHADER, F::SHADER_STORAGE_WRITE),
        (S::COMPUTE_SHADER, F::SHADER_STORAGE_WRITE),
    );
}

#[test]
fn compute_write_storage_image_then_compute_sample() {
    // "Dispatch writes into a storage image. Dispatch samples from that image."
    let b = image_barrier(
        vk::Image::null(),
        range(),
        A::ComputeShaderWrite,
        A::ComputeShaderReadSampledImage,
        false,
    );
    assert_eq!(b.src_stage_mask, S::COMPUTE_SHADER);
    assert_eq!(b.src_access_mask, F::SHADER_STORAGE_WRITE);
    assert_eq!(b.dst_stage_mask, S::COMPUTE_SHADER);
    assert_eq!(b.dst_access_mask, F::SHADER_READ);
    assert_eq!(b.old_layout, L::GENERAL);
    assert_eq!(b.new_layout, L::SHADER_READ_ONLY_OPTIMAL);
    assert_eq!(b.src_queue_family_index, vk::QUEUE_FAMILY_IGNORED);
}

#[test]
fn three_dispatches_global_barrier() {
    // "First dispatch writes to a storage image, second writes to a storage buffer, third
    // reads both": one global memory barrier covers both.
    let b = memory_barrier(A::ComputeShaderWrite, A::ComputeShaderReadOther);
    assert_eq!(b.src_stage_mask, S::COMPUTE_SHADER);
    assert_eq!(b.src_access_mask, F::SHADER_STORAGE_WRITE);
    assert_eq!(b.dst_stage_mask, S::COMPUTE_SHADER);
    assert_eq!(b.dst_access_mask, F::SHADER_STORAGE_READ);
}

#[test]
fn compute_write_then_index_buffer() {
    // "Dispatch writes into a storage buffer. Draw consumes that buffer as an index buffer."
    expect(
        masks(A::ComputeShaderWrite, A::IndexBuffer),
        (S::COMPUTE_SHADER, F::SHADER_STORAGE_WRITE),
        (S::INDEX_INPUT, F::INDEX_READ),
    );
}

#[test]
fn compute_write_then_index_buffer_and_compute_uniform() {
    // "... consumed as an index buffer by a draw, and as a uniform buffer by a dispatch."
    expect(
        masks(
            A::ComputeShaderWrite,
            A::IndexBuffer | A::ComputeShaderReadUniformBuffer,
        ),
        (S::COMPUTE_SHADER, F::SHADER_STORAGE_WRITE),
        (
            S::INDEX_INPUT | S::COMPUTE_SHADER,
            F::INDEX_READ | F::UNIFORM_READ,
        ),
    );
}

#[test]
fn compute_write_then_draw_indirect() {
    // "Dispatch writes into a storage buffer. Draw consumes that buffer as a draw indirect buffer."
    expect(
        masks(A::ComputeShaderWrite, A::IndirectBuffer),
        (S::COMPUTE_SHADER, F::SHADER_STORAGE_WRITE),
        (S::DRAW_INDIRECT, F::INDIRECT_COMMAND_READ),
    );
}

#[test]
fn compute_write_vertex_buffer() {
    // Per-vertex results (e.g. ambient occlusion) consumed as a vertex attribute.
    expect(
        masks(A::ComputeShaderWrite, A::VertexBuffer),
        (S::COMPUTE_SHADER, F::SHADER_STORAGE_WRITE),
        (S::VERTEX_ATTRIBUTE_INPUT, F::VERTEX_ATTRIBUTE_READ),
    );
}

#[test]
fn compute_write_image_then_fragment_sample() {
    // "Dispatch writes into a storage image. Draw samples that image in a fragment shader."
    let b = image_barrier(
        vk::Image::null(),
        range(),
        A::ComputeShaderWrite,
        A::FragmentShaderReadSampledImage,
        false,
    );
    assert_eq!(
        (b.src_stage_mask, b.src_access_mask),
        (S::COMPUTE_SHADER, F::SHADER_STORAGE_WRITE)
    );
    assert_eq!(
        (b.dst_stage_mask, b.dst_access_mask),
        (S::FRAGMENT_SHADER, F::SHADER_READ)
    );
    assert_eq!(
        (b.old_layout, b.new_layout),
        (L::GENERAL, L::SHADER_READ_ONLY_OPTIMAL)
    );
}

#[test]
fn color_attachment_write_then_fragment_sample() {
    // "Draw writes to a color attachment. Draw samples from that image in a fragment shader."
    let b = image_barrier(
        vk::Image::null(),
        range(),
        A::ColorAttachmentWrite,
        A::FragmentShaderReadSampledImage,
        false,
    );
    assert_eq!(
        (b.src_stage_mask, b.src_access_mask),
        (S::COLOR_ATTACHMENT_OUTPUT, F::COLOR_ATTACHMENT_WRITE)
    );
    assert_eq!(
        (b.dst_stage_mask, b.dst_access_mask),
        (S::FRAGMENT_SHADER, F::SHADER_READ)
    );
    assert_eq!(
        (b.old_layout, b.new_layout),
        (L::COLOR_ATTACHMENT_OPTIMAL, L::SHADER_READ_ONLY_OPTIMAL)
    );
}

#[test]
fn staging_copy_then_compute_read() {
    // "Upload data via a staging buffer copy; a dispatch then reads it as a storage buffer."
    let b = buffer_barrier(
        vk::Buffer::null(),
        0,
        vk::WHOLE_SIZE,
        A::TransferWrite,
        A::ComputeShaderReadOther,
    );
    assert_eq!(
        (b.src_stage_mask, b.src_access_mask),
        (S::ALL_TRANSFER, F::TRANSFER_WRITE)
    );
    assert_eq!(
        (b.dst_stage_mask, b.dst_access_mask),
        (S::COMPUTE_SHADER, F::SHADER_STORAGE_READ)
    );
    assert_eq!((b.offset, b.size), (0, vk::WHOLE_SIZE));
}

#[test]
fn image_upload_then_fragment_sample() {
    // "Copy from a staging buffer into an image; sample it in a fragment shader."
    let b = image_barrier(
        vk::Image::null(),
        range(),
        A::TransferWrite,
        A::FragmentShaderReadSampledImage,
        false,
    );
    assert_eq!(
        (b.src_stage_mask, b.src_access_mask),
        (S::ALL_TRANSFER, F::TRANSFER_WRITE)
    );
    assert_eq!(
        (b.dst_stage_mask, b.dst_access_mask),
        (S::FRAGMENT_SHADER, F::SHADER_READ)
    );
    assert_eq!(
        (b.old_layout, b.new_layout),
        (L::TRANSFER_DST_OPTIMAL, L::SHADER_READ_ONLY_OPTIMAL)
    );
}

#[test]
fn first_use_of_image_discards_contents() {
    // Transition from UNDEFINED before a copy: nothing to wait for, but the transition must be
    // visible to the copy.
    let b = image_barrier(
        vk::Image::null(),
        range(),
        A::Nothing,
        A::TransferWrite,
        true,
    );
    assert_eq!((b.src_stage_mask, b.src_access_mask), (S::NONE, F::NONE));
    assert_eq!(
        (b.dst_stage_mask, b.dst_access_mask),
        (S::ALL_TRANSFER, F::TRANSFER_WRITE)
    );
    assert_eq!(
        (b.old_layout, b.new_layout),
        (L::UNDEFINED, L::TRANSFER_DST_OPTIMAL)
    );
}

#[test]
fn read_to_read_with_layout_transition_needs_visibility() {
    // Sampled in a fragment shader, then copied out: no write to wait for, but the layout
    // transition must be made visible to the copy.
    let b = image_barrier(
        vk::Image::null(),
        range(),
        A::FragmentShaderReadSampledImage,
        A::TransferRead,
        false,
    );
    assert_eq!(
        (b.src_stage_mask, b.src_access_mask),
        (S::FRAGMENT_SHADER, F::NONE)
    );
    assert_eq!(
        (b.dst_stage_mask, b.dst_access_mask),
        (S::ALL_TRANSFER, F::TRANSFER_READ)
    );
    assert_eq!(
        (b.old_layout, b.new_layout),
        (L::SHADER_READ_ONLY_OPTIMAL, L::TRANSFER_SRC_OPTIMAL)
    );
}

#[test]
fn compute_write_then_host_read() {
    // "Dispatch writes into a storage buffer; the host reads it after waiting on a fence."
    expect(
        masks(A::ComputeShaderWrite, A::HostRead),
        (S::COMPUTE_SHADER, F::SHADER_STORAGE_WRITE),
        (S::HOST, F::HOST_READ),
    );
}

#[test]
fn transfer_write_then_host_read() {
    expect(
        masks(A::TransferWrite, A::HostRead),
        (S::ALL_TRANSFER, F::TRANSFER_WRITE),
        (S::HOST, F::HOST_READ),
    );
}

#[test]
fn host_write_then_compute_read() {
    // Host writes are made available by the submission; the barrier form still names them.
    expect(
        masks(A::HostWrite, A::ComputeShaderReadUniformBuffer),
        (S::HOST, F::HOST_WRITE),
        (S::COMPUTE_SHADER, F::UNIFORM_READ),
    );
}

#[test]
fn multiple_previous_accesses_union_stages_but_only_writes_are_made_available() {
    expect(
        masks(
            A::ComputeShaderWrite | A::FragmentShaderReadOther,
            A::TransferRead,
        ),
        (
            S::COMPUTE_SHADER | S::FRAGMENT_SHADER,
            F::SHADER_STORAGE_WRITE,
        ),
        (S::ALL_TRANSFER, F::TRANSFER_READ),
    );
}

#[test]
fn nothing_to_read_is_a_no_op_dependency() {
    expect(
        masks(A::Nothing, A::ComputeShaderReadOther),
        (S::NONE, F::NONE),
        (S::COMPUTE_SHADER, F::NONE),
    );
}

#[test]
fn general_is_a_full_barrier() {
    expect(
        masks(A::General, A::General),
        (S::ALL_COMMANDS, F::MEMORY_READ | F::MEMORY_WRITE),
        (S::ALL_COMMANDS, F::MEMORY_READ | F::MEMORY_WRITE),
    );
}

#[test]
fn mixed_layouts_fall_back_to_general() {
    let set = A::ComputeShaderReadSampledImage | A::ComputeShaderWrite;
    assert_eq!(set.layout(), L::GENERAL);
    assert_eq!(
        AccessSet::from(A::TransferRead).layout(),
        L::TRANSFER_SRC_OPTIMAL
    );
    assert_eq!(
        AccessSet::from(A::ComputeShaderReadUniformBuffer).layout(),
        L::UNDEFINED
    );
}

#[test]
fn every_write_access_has_write_flags_and_reads_have_none() {
    let write_bits = F::SHADER_STORAGE_WRITE
        | F::COLOR_ATTACHMENT_WRITE
        | F::DEPTH_STENCIL_ATTACHMENT_WRITE
        | F::TRANSFER_WRITE
        | F::HOST_WRITE
        | F::MEMORY_WRITE;
    for a in A::ALL {
        let info = a.info();
        assert_eq!(
            a.is_write(),
            info.access.intersects(write_bits),
            "{a:?}: is_write disagrees with its access flags {:?}",
            info.access
        );
        assert_eq!(a == A::Nothing, info.stages.is_empty(), "{a:?} stage mask");
    }
}

#[test]
fn access_set_membership() {
    let s = A::TransferRead | A::ComputeShaderReadOther | A::HostRead;
    assert!(s.contains(A::TransferRead) && s.contains(A::HostRead));
    assert!(!s.contains(A::TransferWrite));
    assert_eq!(s.iter().count(), 3);
    assert!(AccessSet::from(A::Nothing).is_empty());
}
