//! Image transfers: staged uploads and readbacks, copies, clears, blits and mip chains, and
//! a streamed upload for images larger than the staging ring.

use super::{Readback, Recorder};
use crate::error::{Error, Result};
use crate::gpu::context::Context;
use crate::gpu::image::{Image, ImageRegion, Subresources};
use crate::gpu::sync::AccessType;
use ash::vk;

impl Recorder {
    /// Copies tightly packed texels into `region` of `image` through staging (a tracked
    /// `TransferWrite`; a region covering the whole mip level discards its old contents).
    pub fn upload_image(&mut self, image: &Image, region: ImageRegion, data: &[u8]) -> Result<()> {
        self.owns_image(image)?;
        region.check(image.name(), image.desc())?;
        image.require_usage(vk::ImageUsageFlags::TRANSFER_DST, "an upload to it")?;
        let block = image.desc().block()?;
        let expected = region.byte_size(image.desc())?;
        if data.len() as u64 != expected {
            return Err(Error::InvalidArgument(format!(
                "region {:?} of image '{}' needs {expected} bytes of texels, got {}",
                region.extent,
                image.name(),
                data.len()
            )));
        }
        // bufferOffset: a multiple of the texel block size and of 4.
        let (src, offset) = self.stage(image.name(), data, block.bytes.max(4))?;
        let whole = region.offset == [0; 3] && region.extent == image.desc().mip_extent(region.mip);
        self.use_image_inner(
            &image.keep(),
            region.subresources(),
            AccessType::TransferWrite.into(),
            whole,
        );
        self.flush_barriers();
        // SAFETY: recording; the subresources are in TRANSFER_DST_OPTIMAL after the barrier.
        unsafe {
            self.device().cmd_copy_buffer_to_image(
                self.cmd,
                src,
                image.raw(),
                vk::ImageLayout::TRANSFER_DST_OPTIMAL,
                &[copy_region(&region, offset)],
            )
        };
        Ok(())
    }

    /// Copies tightly packed texels, row after row, into the first rows of mip 0 of
    /// `image` (a 2D image, layer 0, uncompressed format), the last row padded with zero
    /// texels; records nothing for empty `data`. An error if the texels need more rows
    /// than the image has.
    pub fn upload_image_rows<T: bytemuck::Pod>(&mut self, image: &Image, data: &[T]) -> Result<()> {
        let data: &[u8] = bytemuck::cast_slice(data);
        let texel = image.desc().texel_size()?;
        let [width, height, _] = image.desc().extent;
        let row_bytes = width as u64 * texel;
        let bytes = data.len() as u64;
        let rows = bytes.div_ceil(row_bytes);
        if !bytes.is_multiple_of(texel) || rows > height as u64 {
            return Err(Error::InvalidArgument(format!(
                "{bytes} bytes of texels do not fill whole texels of image '{}' or do not fit \
                 it ({width} x {height}, {texel} bytes a texel)",
                image.name()
            )));
        }
        if rows == 0 {
            return Ok(());
        }
        let mut padded = data.to_vec();
        padded.resize((rows * row_bytes) as usize, 0);
        let region = ImageRegion {
            layers: 1,
            extent: [width, rows as u32, 1],
            ..ImageRegion::whole(image.desc())
        };
        self.upload_image(image, region, &padded)
    }

    /// Copies `region` of `image` back to the host, tightly packed (a tracked `TransferRead`).
    pub fn read_back_image(&mut self, image: &Image, region: ImageRegion) -> Result<Readback> {
        region.check(image.name(), image.desc())?;
        image.require_usage(vk::ImageUsageFlags::TRANSFER_SRC, "a readback")?;
        let size = region.byte_size(image.desc())?;
        let (staging, readback) = self.readback_buffer(image.name(), size)?;
        self.use_image(image, region.subresources(), AccessType::TransferRead)?;
        self.local.declare_buffer(&staging.keep(), |s| {
            *s = crate::gpu::track::BufferState::after(AccessType::TransferWrite.into())
        });
        self.flush_barriers();
        // SAFETY: recording; the subresources are in TRANSFER_SRC_OPTIMAL after the barrier.
        unsafe {
            self.device().cmd_copy_image_to_buffer(
                self.cmd,
                image.raw(),
                vk::ImageLayout::TRANSFER_SRC_OPTIMAL,
                staging.raw(),
                &[copy_region(&region, 0)],
            )
        };
        Ok(readback)
    }

    /// Declares `src_region` of `src` a `TransferRead` and `dst_region` of `dst` a
    /// `TransferWrite` (discarding the old contents when it covers the whole mip level),
    /// and records the barriers.
    fn use_for_transfer(
        &mut self,
        src: &Image,
        src_region: &ImageRegion,
        dst: &Image,
        dst_region: &ImageRegion,
    ) -> Result<()> {
        self.owns_image(src)?;
        self.owns_image(dst)?;
        src.require_usage(vk::ImageUsageFlags::TRANSFER_SRC, "a transfer from it")?;
        dst.require_usage(vk::ImageUsageFlags::TRANSFER_DST, "a transfer to it")?;
        self.use_image(src, src_region.subresources(), AccessType::TransferRead)?;
        let whole = dst_region.offset == [0; 3]
            && dst_region.extent == dst.desc().mip_extent(dst_region.mip);
        self.use_image_inner(
            &dst.keep(),
            dst_region.subresources(),
            AccessType::TransferWrite.into(),
            whole,
        );
        self.flush_barriers();
        Ok(())
    }

    /// Copies `src_region` of `src` to `dst` at `dst_region` (same extent; formats of the
    /// same texel size).
    pub fn copy_image(
        &mut self,
        src: &Image,
        src_region: ImageRegion,
        dst: &Image,
        dst_region: ImageRegion,
    ) -> Result<()> {
        src_region.check(src.name(), src.desc())?;
        dst_region.check(dst.name(), dst.desc())?;
        if src_region.extent != dst_region.extent || src_region.layers != dst_region.layers {
            return Err(Error::InvalidArgument(format!(
                "image copy from '{}' {:?}x{} to '{}' {:?}x{}: extents and layer counts must match",
                src.name(),
                src_region.extent,
                src_region.layers,
                dst.name(),
                dst_region.extent,
                dst_region.layers
            )));
        }
        if src.desc().texel_size()? != dst.desc().texel_size()? {
            return Err(Error::InvalidArgument(format!(
                "image copy from '{}' ({:?}) to '{}' ({:?}): texel sizes differ",
                src.name(),
                src.desc().format,
                dst.name(),
                dst.desc().format
            )));
        }
        if src.raw() == dst.raw() {
            return Err(Error::InvalidArgument(format!(
                "image copy within '{}': use two images",
                src.name()
            )));
        }
        self.use_for_transfer(src, &src_region, dst, &dst_region)?;
        let to_offset = |o: [u32; 3]| vk::Offset3D {
            x: o[0] as i32,
            y: o[1] as i32,
            z: o[2] as i32,
        };
        let region = vk::ImageCopy {
            src_subresource: src_region.layers_vk(),
            src_offset: to_offset(src_region.offset),
            dst_subresource: dst_region.layers_vk(),
            dst_offset: to_offset(dst_region.offset),
            extent: vk::Extent3D {
                width: src_region.extent[0],
                height: src_region.extent[1],
                depth: src_region.extent[2],
            },
        };
        // SAFETY: recording; layouts set by the barriers above; regions checked.
        unsafe {
            self.device().cmd_copy_image(
                self.cmd,
                src.raw(),
                vk::ImageLayout::TRANSFER_SRC_OPTIMAL,
                dst.raw(),
                vk::ImageLayout::TRANSFER_DST_OPTIMAL,
                &[region],
            )
        };
        Ok(())
    }

    /// Clears `range` of `image` to `color` (float formats; a tracked `TransferWrite` that
    /// discards the old contents).
    pub fn clear_image(
        &mut self,
        image: &Image,
        range: Subresources,
        color: [f32; 4],
    ) -> Result<()> {
        self.owns_image(image)?;
        range.check(image.name(), image.desc())?;
        if !image
            .desc()
            .usage
            .contains(vk::ImageUsageFlags::TRANSFER_DST)
        {
            return Err(Error::InvalidArgument(format!(
                "image '{}' lacks TRANSFER_DST usage, needed to clear it",
                image.name()
            )));
        }
        self.use_image_inner(&image.keep(), range, AccessType::TransferWrite.into(), true);
        self.flush_barriers();
        let value = vk::ClearColorValue { float32: color };
        // SAFETY: recording; the range is in TRANSFER_DST_OPTIMAL.
        unsafe {
            self.device().cmd_clear_color_image(
                self.cmd,
                image.raw(),
                vk::ImageLayout::TRANSFER_DST_OPTIMAL,
                &value,
                &[range.vk()],
            )
        };
        Ok(())
    }

    /// Scales `src_region` of `src` into `dst_region` of `dst` with `filter` (format
    /// features BLIT_SRC/BLIT_DST, and linear filtering for `LINEAR`, are checked).
    pub fn blit_image(
        &mut self,
        src: &Image,
        src_region: ImageRegion,
        dst: &Image,
        dst_region: ImageRegion,
        filter: vk::Filter,
    ) -> Result<()> {
        src_region.check(src.name(), src.desc())?;
        dst_region.check(dst.name(), dst.desc())?;
        let mut src_needs = vk::FormatFeatureFlags::BLIT_SRC;
        if filter == vk::Filter::LINEAR {
            src_needs |= vk::FormatFeatureFlags::SAMPLED_IMAGE_FILTER_LINEAR;
        }
        self.shared.require_format(
            src.desc().format,
            src_needs,
            &format!("blitting from '{}'", src.name()),
        )?;
        self.shared.require_format(
            dst.desc().format,
            vk::FormatFeatureFlags::BLIT_DST,
            &format!("blitting to '{}'", dst.name()),
        )?;
        if src_region.layers != dst_region.layers {
            return Err(Error::InvalidArgument(format!(
                "blit from '{}' to '{}': layer counts differ",
                src.name(),
                dst.name()
            )));
        }
        let same = src.raw() == dst.raw();
        if same && src_region.mip == dst_region.mip {
            return Err(Error::InvalidArgument(format!(
                "blit within one mip level of '{}'",
                src.name()
            )));
        }
        self.use_for_transfer(src, &src_region, dst, &dst_region)?;
        let corners = |r: &ImageRegion| {
            [
                vk::Offset3D {
                    x: r.offset[0] as i32,
                    y: r.offset[1] as i32,
                    z: r.offset[2] as i32,
                },
                vk::Offset3D {
                    x: (r.offset[0] + r.extent[0]) as i32,
                    y: (r.offset[1] + r.extent[1]) as i32,
                    z: (r.offset[2] + r.extent[2]) as i32,
                },
            ]
        };
        let blit = vk::ImageBlit {
            src_subresource: src_region.layers_vk(),
            src_offsets: corners(&src_region),
            dst_subresource: dst_region.layers_vk(),
            dst_offsets: corners(&dst_region),
        };
        // SAFETY: recording; layouts set by the barriers above; regions and features checked.
        unsafe {
            self.device().cmd_blit_image(
                self.cmd,
                src.raw(),
                vk::ImageLayout::TRANSFER_SRC_OPTIMAL,
                dst.raw(),
                vk::ImageLayout::TRANSFER_DST_OPTIMAL,
                &[blit],
                filter,
            )
        };
        Ok(())
    }

    /// Fills mips 1.. of `image` by successive linear blits from mip 0.
    pub fn generate_mips(&mut self, image: &Image) -> Result<()> {
        let desc = *image.desc();
        for mip in 1..desc.mips {
            self.blit_image(
                image,
                ImageRegion::mip(&desc, mip - 1),
                image,
                ImageRegion::mip(&desc, mip),
                vk::Filter::LINEAR,
            )?;
        }
        Ok(())
    }
}

fn copy_region(region: &ImageRegion, buffer_offset: u64) -> vk::BufferImageCopy {
    vk::BufferImageCopy {
        buffer_offset,
        buffer_row_length: 0,
        buffer_image_height: 0,
        image_subresource: region.layers_vk(),
        image_offset: vk::Offset3D {
            x: region.offset[0] as i32,
            y: region.offset[1] as i32,
            z: region.offset[2] as i32,
        },
        image_extent: vk::Extent3D {
            width: region.extent[0],
            height: region.extent[1],
            depth: region.extent[2],
        },
    }
}

impl Context {
    /// Uploads mip 0 of `image` (tightly packed texels, all layers) in chunks of at most
    /// `chunk_bytes` (whole rows, slices or layers), each recorded and submitted on its own
    /// and staged through the ring, so a large texture volume needs no staging buffer of its
    /// size. Returns the timeline value of the last chunk (see [`Context::wait_for`]).
    pub fn upload_image_streamed(
        &self,
        image: &Image,
        data: &[u8],
        chunk_bytes: u64,
    ) -> Result<u64> {
        let desc = *image.desc();
        let block = desc.block()?;
        let [w, h, d] = desc.extent;
        if data.len() as u64 != desc.byte_size()? {
            return Err(Error::InvalidArgument(format!(
                "image '{}' needs {} bytes of texels, got {}",
                image.name(),
                desc.byte_size()?,
                data.len()
            )));
        }
        // A row of texel blocks (a row of texels for an uncompressed format).
        let row = block.bytes_for([w, 1, 1]);
        let slice = block.bytes_for([w, h, 1]);
        // Units along the slowest axis: layers (2D arrays), depth slices (3D) or block rows.
        let (units, unit_bytes) = if desc.layers > 1 {
            (desc.layers, slice)
        } else if d > 1 {
            (d, slice)
        } else {
            (h.div_ceil(block.height), row)
        };
        let per_chunk = (chunk_bytes / unit_bytes).clamp(1, units as u64) as u32;
        let mut last = 0;
        let mut start = 0u32;
        while start < units {
            let n = per_chunk.min(units - start);
            let mut region = ImageRegion::whole(&desc);
            if desc.layers > 1 {
                region.base_layer = start;
                region.layers = n;
            } else if d > 1 {
                region.offset[2] = start;
                region.extent[2] = n;
            } else {
                region.offset[1] = start * block.height;
                region.extent[1] = (n * block.height).min(h - region.offset[1]);
            }
            let bytes = &data
                [(start as u64 * unit_bytes) as usize..((start + n) as u64 * unit_bytes) as usize];
            let mut rec = self.recorder(&format!("upload {} part {start}", image.name()))?;
            rec.upload_image(image, region, bytes)?;
            last = rec.submit()?.value();
            start += n;
        }
        Ok(last)
    }
}
