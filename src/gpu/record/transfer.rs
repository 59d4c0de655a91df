//! Buffer transfers: copies, fills, staged uploads and readbacks, and the [`Context`]
//! conveniences that record, submit and wait for one of them.

use super::Recorder;
use crate::error::{Error, Result};
use crate::gpu::context::Context;
use crate::gpu::memory::{Buffer, BufferDesc, require_buffer_usage};
use crate::gpu::sync::AccessType;
use ash::vk;

/// Data copied back to the host by a recording; readable once the recording is submitted
/// (reading waits for the submission to complete).
pub struct Readback {
    /// Stamped with the submission's timeline value when the recording is submitted (0
    /// until then). May be larger than the data (pooled staging is reused).
    staging: Buffer,
    /// Bytes read back.
    len: u64,
}

impl Readback {
    /// The bytes read back (waits for the submission). Fails if the recording was not
    /// submitted.
    pub fn bytes(&self) -> Result<Vec<u8>> {
        self.to_vec::<u8>()
    }

    /// The data read back as a vector of `T` (waits for the submission).
    pub fn to_vec<T: bytemuck::Pod>(&self) -> Result<Vec<T>> {
        crate::gpu::memory::not_zero_sized::<T>()?;
        if self.staging.last_use() == 0 {
            return Err(Error::InvalidArgument(format!(
                "readback '{}' read before its recording was submitted",
                self.staging.name()
            )));
        }
        let n = self.len as usize / std::mem::size_of::<T>();
        let mut out = vec![T::zeroed(); n];
        self.staging.read_into(0, &mut out)?;
        Ok(out)
    }
}

impl Recorder {
    /// Copies `size` bytes between buffers, with the barriers the tracked state calls for
    /// (`TransferRead` of `src`, `TransferWrite` of `dst`).
    pub fn copy_buffer(
        &mut self,
        src: &Buffer,
        src_offset: u64,
        dst: &Buffer,
        dst_offset: u64,
        size: u64,
    ) -> Result<()> {
        let fits = |offset: u64, len: u64| offset.checked_add(size).is_some_and(|end| end <= len);
        if size == 0 || !fits(src_offset, src.size()) || !fits(dst_offset, dst.size()) {
            return Err(Error::InvalidArgument(format!(
                "copy of {size} bytes from '{}'+{src_offset} to '{}'+{dst_offset} is empty or out of bounds",
                src.name(),
                dst.name()
            )));
        }
        if src.raw() == dst.raw() {
            return Err(Error::InvalidArgument(format!(
                "copy within buffer '{}': use two buffers",
                src.name()
            )));
        }
        require_buffer_usage(src, vk::BufferUsageFlags::TRANSFER_SRC, "a copy from it")?;
        require_buffer_usage(dst, vk::BufferUsageFlags::TRANSFER_DST, "a copy to it")?;
        self.use_buffer(src, AccessType::TransferRead)?;
        self.use_buffer(dst, AccessType::TransferWrite)?;
        self.flush_barriers();
        let region = vk::BufferCopy {
            src_offset,
            dst_offset,
            size,
        };
        // SAFETY: recording; bounds checked; both kept alive.
        unsafe {
            self.device()
                .cmd_copy_buffer(self.cmd, src.raw(), dst.raw(), &[region])
        };
        Ok(())
    }

    /// Fills a whole buffer with a repeated 32-bit value (a tracked `TransferWrite`).
    pub fn fill_buffer(&mut self, buffer: &Buffer, value: u32) -> Result<()> {
        require_buffer_usage(buffer, vk::BufferUsageFlags::TRANSFER_DST, "fill_buffer")?;
        self.use_buffer(buffer, AccessType::TransferWrite)?;
        self.flush_barriers();
        // SAFETY: recording; kept alive.
        unsafe {
            self.device()
                .cmd_fill_buffer(self.cmd, buffer.raw(), 0, vk::WHOLE_SIZE, value)
        };
        Ok(())
    }

    /// Staging space holding `bytes`: a chunk of the context's ring when it has room
    /// (waiting for earlier submissions to give space back), else a one-off buffer kept
    /// by this recording. Returns (buffer, offset).
    pub(super) fn stage(
        &mut self,
        what: &str,
        bytes: &[u8],
        align: u64,
    ) -> Result<(vk::Buffer, u64)> {
        if let Some((id, offset)) = self.shared.ring_alloc(bytes.len() as u64, align)? {
            self.ring_chunks.push(id);
            // SAFETY: the chunk [offset, offset + len) is ours alone until this recording is
            // submitted and completes; the ring's mapping covers it.
            unsafe { self.shared.ring_write(offset, bytes) };
            return Ok((self.shared.ring_buffer(), offset));
        }
        let ctx = self.context();
        let staging = Buffer::new(
            &ctx,
            &format!("{what} staging"),
            BufferDesc::upload(bytes.len() as u64),
        )?;
        staging.write(0, bytes)?;
        let raw = staging.raw();
        self.keep.add(staging.keep());
        Ok((raw, 0))
    }

    /// Copies `data` into `dst` at `offset` through staging (a tracked `TransferWrite`).
    pub fn upload<T: bytemuck::Pod>(
        &mut self,
        dst: &Buffer,
        offset: u64,
        data: &[T],
    ) -> Result<()> {
        let bytes: &[u8] = bytemuck::cast_slice(data);
        if bytes.is_empty() {
            return Ok(());
        }
        if offset
            .checked_add(bytes.len() as u64)
            .is_none_or(|end| end > dst.size())
        {
            return Err(Error::InvalidArgument(format!(
                "upload of {} bytes at offset {offset} overruns buffer '{}' of {} bytes",
                bytes.len(),
                dst.name(),
                dst.size()
            )));
        }
        let (src, src_offset) = self.stage(dst.name(), bytes, 4)?;
        self.use_buffer(dst, AccessType::TransferWrite)?;
        self.flush_barriers();
        let region = vk::BufferCopy {
            src_offset,
            dst_offset: offset,
            size: bytes.len() as u64,
        };
        // SAFETY: recording; staging holds the bytes and stays alive until completion.
        unsafe {
            self.device()
                .cmd_copy_buffer(self.cmd, src, dst.raw(), &[region])
        };
        Ok(())
    }

    pub(super) fn readback_buffer(&mut self, what: &str, size: u64) -> Result<(Buffer, Readback)> {
        let ctx = self.context();
        let staging = Buffer::readback_staging(&ctx, &format!("{what} readback"), size)?;
        self.keep.add(staging.keep());
        self.needs_host_barrier = true;
        let handle = Buffer::from_keep(staging.keep());
        Ok((
            staging,
            Readback {
                staging: handle,
                len: size,
            },
        ))
    }

    /// Copies a whole buffer back to the host (a tracked `TransferRead`).
    pub fn read_back(&mut self, buffer: &Buffer) -> Result<Readback> {
        self.read_back_range(buffer, 0, buffer.size())
    }

    /// Copies `size` bytes from `offset` of `buffer` back to the host.
    pub fn read_back_range(&mut self, buffer: &Buffer, offset: u64, size: u64) -> Result<Readback> {
        if size == 0
            || offset
                .checked_add(size)
                .is_none_or(|end| end > buffer.size())
        {
            return Err(Error::InvalidArgument(format!(
                "readback of {size} bytes at {offset} is empty or outside buffer '{}' ({} bytes)",
                buffer.name(),
                buffer.size()
            )));
        }
        require_buffer_usage(buffer, vk::BufferUsageFlags::TRANSFER_SRC, "a readback")?;
        let (staging, readback) = self.readback_buffer(buffer.name(), size)?;
        self.use_buffer(buffer, AccessType::TransferRead)?;
        self.local.declare_buffer(&staging.keep(), |s| {
            *s = crate::gpu::track::BufferState::after(AccessType::TransferWrite.into())
        });
        self.flush_barriers();
        let region = vk::BufferCopy {
            src_offset: offset,
            dst_offset: 0,
            size,
        };
        // SAFETY: recording; both buffers kept alive; bounds checked.
        unsafe {
            self.device()
                .cmd_copy_buffer(self.cmd, buffer.raw(), staging.raw(), &[region])
        };
        Ok(readback)
    }
}

impl Recorder {
    /// Creates a buffer and records the upload of `data` into it (kernel construction uses
    /// this: the upload runs with the caller's submission).
    pub fn buffer_with<T: bytemuck::Pod>(
        &mut self,
        name: &str,
        desc: BufferDesc,
        data: &[T],
    ) -> Result<Buffer> {
        let bytes = std::mem::size_of_val(data) as u64;
        if bytes > desc.size {
            return Err(Error::InvalidArgument(format!(
                "{bytes} bytes of data do not fit buffer '{name}' of {} bytes",
                desc.size
            )));
        }
        let desc = desc.usage(vk::BufferUsageFlags::TRANSFER_DST);
        let buffer = Buffer::new(&self.context(), name, desc)?;
        self.upload(&buffer, 0, data)?;
        Ok(buffer)
    }
}

impl Context {
    /// Creates a buffer holding `data`: records the upload, submits and waits. A convenience
    /// for tests and tools; kernels record uploads with [`Recorder::buffer_with`].
    pub fn upload_buffer<T: bytemuck::Pod>(
        &self,
        name: &str,
        desc: BufferDesc,
        data: &[T],
    ) -> Result<Buffer> {
        let mut rec = self.recorder(&format!("upload {name}"))?;
        let buffer = rec.buffer_with(name, desc, data)?;
        rec.submit_and_wait()?;
        Ok(buffer)
    }

    /// Reads a whole buffer back to the host: records the copy, submits and waits.
    pub fn read_buffer<T: bytemuck::Pod>(&self, buffer: &Buffer) -> Result<Vec<T>> {
        let mut rec = self.recorder(&format!("read {}", buffer.name()))?;
        let rb = rec.read_back(buffer)?;
        rec.submit_and_wait()?;
        rb.to_vec()
    }
}

impl std::fmt::Debug for Readback {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Readback")
            .field("staging", &self.staging.name())
            .field("len", &self.len)
            .finish()
    }
}
