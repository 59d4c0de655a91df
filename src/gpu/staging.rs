//! The staging ring: one host-visible upload buffer, reused frame after frame.
//!
//! Recordings take chunks from the ring in order; a chunk is given back when the timeline
//! reaches the value of the submission that used it (or at once when its recording is
//! dropped unsubmitted). A chunk whose recording is leaked is never given back: the ring then
//! fills up and uploads fall back to one-off staging buffers, which is slower but never
//! unsound.

use super::context::Shared;
use super::memory::{Dedicated, MappedPtr, Placement};
use super::validation::lock;
use crate::error::{Result, VkResultExt};
use ash::vk;
use gpu_allocator::vulkan::{Allocation, AllocationScheme};
use std::collections::VecDeque;

/// Where a chunk stands.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum ChunkState {
    /// Taken by a recording that has not been submitted.
    Recording,
    /// Used by the submission signalling this value (0: never submitted, free).
    Submitted(u64),
}

#[derive(Debug)]
struct Chunk {
    id: u64,
    /// First byte occupied (including alignment or wrap-around padding before the data).
    start: u64,
    end: u64,
    state: ChunkState,
}

/// Bookkeeping of the ring (the buffer itself lives in the context).
#[derive(Debug)]
pub(crate) struct Ring {
    capacity: u64,
    head: u64,
    live: VecDeque<Chunk>,
    next_id: u64,
    in_use: u64,
    peak_in_use: u64,
}

impl Ring {
    pub fn new(capacity: u64) -> Ring {
        Ring {
            capacity,
            head: 0,
            live: VecDeque::new(),
            next_id: 1,
            in_use: 0,
            peak_in_use: 0,
        }
    }

    pub fn capacity(&self) -> u64 {
        self.capacity
    }

    /// Highest number of bytes held at once (padding included).
    pub fn peak_in_use(&self) -> u64 {
        self.peak_in_use
    }

    /// Takes `len` bytes aligned to `align`; returns (chunk id, offset of the data).
    pub fn alloc(&mut self, len: u64, align: u64) -> Option<(u64, u64)> {
        let align = align.max(1);
        if len == 0 || len > self.capacity {
            return None;
        }
        let (start, data) = if self.live.is_empty() {
            self.head = 0;
            (0, 0)
        } else {
            let tail = self.live.front().map(|c| c.start).unwrap_or(0);
            let aligned = self.head.next_multiple_of(align);
            if self.head > tail {
                if aligned + len <= self.capacity {
                    (self.head, aligned)
                } else if len <= tail {
                    (self.head, 0)
                } else {
                    return None;
                }
            } else if self.head < tail && aligned + len <= tail {
                (self.head, aligned)
            } else {
                return None;
            }
        };
        let end = data + len;
        let id = self.next_id;
        self.next_id += 1;
        let held = if end >= start {
            end - start
        } else {
            self.capacity - start + end
        };
        self.in_use += held;
        self.peak_in_use = self.peak_in_use.max(self.in_use);
        self.live.push_back(Chunk {
            id,
            start,
            end,
            state: ChunkState::Recording,
        });
        self.head = if end == self.capacity { 0 } else { end };
        Some((id, data))
    }

    /// Marks chunks as used by the submission signalling `value` (0: released unsubmitted).
    pub fn mark(&mut self, ids: &[u64], value: u64) {
        for c in self.live.iter_mut().filter(|c| ids.contains(&c.id)) {
            c.state = ChunkState::Submitted(value);
        }
    }

    /// Gives back the chunks at the front whose submissions have completed.
    pub fn reclaim(&mut self, completed: u64) {
        while let Some(c) = self.live.front() {
            match c.state {
                ChunkState::Submitted(v) if v <= completed => {
                    let held = if c.end >= c.start {
                        c.end - c.start
                    } else {
                        self.capacity - c.start + c.end
                    };
                    self.in_use -= held;
                    self.live.pop_front();
                }
                _ => break,
            }
        }
        if self.live.is_empty() {
            self.head = 0;
            self.in_use = 0;
        }
    }

    /// The value to wait for before the oldest chunk can be given back (`None` if it belongs
    /// to a recording not yet submitted, or the ring is empty).
    pub fn oldest_value(&self) -> Option<u64> {
        match self.live.front()?.state {
            ChunkState::Submitted(v) => Some(v),
            ChunkState::Recording => None,
        }
    }
}

/// The ring's bookkeeping and its buffer (created on first use).
pub(crate) struct StagingRing {
    pub ring: Ring,
    pub buffer: vk::Buffer,
    pub allocation: Option<Allocation>,
    ptr: Option<MappedPtr>,
}

impl StagingRing {
    pub fn new(capacity: u64) -> Self {
        StagingRing {
            ring: Ring::new(capacity),
            buffer: vk::Buffer::null(),
            allocation: None,
            ptr: None,
        }
    }

    pub fn capacity(&self) -> u64 {
        self.ring.capacity()
    }

    pub fn mark(&mut self, ids: &[u64], value: u64) {
        self.ring.mark(ids, value);
    }
}

/// How long an upload waits for ring space held by submitted work before it falls back to a
/// one-off staging buffer.
const RING_WAIT_NS: u64 = 10_000_000_000;

impl Shared {
    /// Creates the ring's buffer on first use.
    fn ring_buffer_init(&self, st: &mut StagingRing) -> Result<()> {
        if st.buffer != vk::Buffer::null() {
            return Ok(());
        }
        let info = vk::BufferCreateInfo::default()
            .size(st.ring.capacity())
            .usage(vk::BufferUsageFlags::TRANSFER_SRC)
            .sharing_mode(vk::SharingMode::EXCLUSIVE);
        // SAFETY: valid device and create info.
        let buffer = unsafe { self.device.create_buffer(&info, None) }.vk("vkCreateBuffer")?;
        // SAFETY: just created.
        let req = unsafe { self.device.get_buffer_memory_requirements(buffer) };
        let allocation = match self.allocate(
            "vkshade staging ring",
            req,
            Placement::UPLOAD.dedicated(Dedicated::Always),
            true,
            (AllocationScheme::DedicatedBuffer(buffer), true, false),
        ) {
            Ok(a) => a,
            Err(e) => {
                // SAFETY: unused.
                unsafe { self.device.destroy_buffer(buffer, None) };
                return Err(e);
            }
        };
        // SAFETY: memory of this device sized for the buffer.
        let bound = unsafe {
            self.device
                .bind_buffer_memory(buffer, allocation.memory(), allocation.offset())
        };
        let ptr = allocation.mapped_ptr().map(|p| MappedPtr(p.cast()));
        if let Err(e) = bound.vk("vkBindBufferMemory") {
            // SAFETY: unused.
            unsafe {
                self.device.destroy_buffer(buffer, None);
                self.free_memory(allocation);
            }
            return Err(e);
        }
        self.set_name(buffer, "vkshade staging ring");
        st.buffer = buffer;
        st.allocation = Some(allocation);
        st.ptr = ptr;
        Ok(())
    }

    /// Takes `len` bytes of the ring (waiting for submitted work to give space back);
    /// `None` when the request cannot be served from the ring.
    pub(crate) fn ring_alloc(&self, len: u64, align: u64) -> Result<Option<(u64, u64)>> {
        loop {
            let mut st = lock(&self.staging);
            if len > st.ring.capacity() {
                return Ok(None);
            }
            self.ring_buffer_init(&mut st)?;
            st.ring.reclaim(self.completed());
            if let Some(r) = st.ring.alloc(len, align) {
                return Ok(Some(r));
            }
            match st.ring.oldest_value() {
                Some(v) if v > 0 => {
                    drop(st);
                    if !self.wait_value(v, RING_WAIT_NS)? {
                        return Ok(None);
                    }
                }
                _ => return Ok(None),
            }
        }
    }

    /// Copies `bytes` into the ring at `offset`.
    ///
    /// # Safety
    /// `[offset, offset + bytes.len())` must be a chunk from [`Shared::ring_alloc`] that no
    /// submitted work uses yet.
    pub(crate) unsafe fn ring_write(&self, offset: u64, bytes: &[u8]) {
        let st = lock(&self.staging);
        let ptr = st.ptr.expect("ring buffers are host-visible");
        // SAFETY: the caller guarantees the chunk is ours and inside the mapping.
        unsafe {
            std::ptr::copy_nonoverlapping(
                bytes.as_ptr(),
                ptr.0.as_ptr().add(offset as usize),
                bytes.len(),
            )
        };
    }

    pub(crate) fn ring_buffer(&self) -> vk::Buffer {
        lock(&self.staging).buffer
    }

    /// Peak bytes of the ring held at once.
    pub(crate) fn ring_peak(&self) -> u64 {
        lock(&self.staging).ring.peak_in_use()
    }
}

#[cfg(test)]
mod tests {
    use super::Ring;

    #[test]
    fn chunks_are_reused_after_their_submission_completes() {
        let mut r = Ring::new(100);
        let (a, oa) = r.alloc(40, 4).unwrap();
        let (b, ob) = r.alloc(40, 4).unwrap();
        assert_eq!((oa, ob), (0, 40));
        assert!(r.alloc(40, 4).is_none(), "full");
        r.mark(&[a], 1);
        r.mark(&[b], 2);
        r.reclaim(0);
        assert!(r.alloc(40, 4).is_none(), "nothing completed yet");
        r.reclaim(1);
        let (c, oc) = r.alloc(30, 4).unwrap();
        assert_eq!(oc, 0, "wraps to the front");
        assert!(
            r.alloc(30, 4).is_none(),
            "only 20 + 10 bytes free, not contiguous"
        );
        r.mark(&[c], 0);
        r.reclaim(2);
        assert!(r.alloc(100, 4).is_some(), "all free again");
    }

    #[test]
    fn random_use_never_overlaps_live_chunks() {
        let mut r = Ring::new(1000);
        let mut live: Vec<(u64, u64, u64, u64)> = Vec::new(); // id, start, end, value
        let mut seed = 7u64;
        let mut rand = |n: u64| {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (seed >> 33) % n
        };
        let mut value = 0u64;
        let mut done = 0u64;
        for _ in 0..5000 {
            if rand(3) > 0 {
                let len = 1 + rand(300);
                if let Some((id, off)) = r.alloc(len, 1 << rand(5)) {
                    for &(_, s, e, _) in &live {
                        assert!(off + len <= s || off >= e, "overlap");
                    }
                    value += 1;
                    r.mark(&[id], value);
                    live.push((id, off, off + len, value));
                }
            } else {
                done = (done + 1 + rand(3)).min(value);
                r.reclaim(done);
                let front_gone = |v: u64| v <= done;
                // The ring gives back in order; keep what it may still hold.
                while live.first().is_some_and(|c| front_gone(c.3)) {
                    live.remove(0);
                }
            }
        }
    }
}
