//! What one recording assumes and does, per resource, kept apart from the resources' tracked
//! state until the recording is submitted.
//!
//! A recording cannot know the state its resources will be in when it runs: recordings may be
//! submitted in another order than they were recorded, or dropped unsubmitted. So each
//! recording tracks its resources *locally*, from their first use in it:
//! - the first use of a buffer or image subresource records no barrier; it becomes the
//!   recording's *entry* for that resource (for a run of reads in one layout, the union of
//!   them, since reads need no barrier among themselves);
//! - later uses are tracked as usual against the local state, whose history starts at the
//!   entry.
//!
//! At submission ([`LocalTracker::resolve`], under the queue lock, in submission order) each
//! entry is joined to the resource's true state: the barrier from everything before to the
//! entry (its layout transition included) is recorded into a *prologue* command buffer that
//! runs just before the recording in the same batch, and the resource's state becomes the
//! local end state. Everything earlier is ordered before the entry, and the entry before every
//! later access in the recording, so the local state describes the resource completely.
//! A recording that only reads a resource in one layout joins exactly as if its reads were
//! declared at submission (no barrier when the state needs none).
//!
//! A dropped recording never resolves: the tracked state is as if it never existed.
//!
//! A recording into a caller's command buffer ([`Context::record_into`]) cannot put barriers
//! before its own commands at submission, which the caller makes. It joins each resource at
//! its first use against the state committed so far, and commits its end state when it is
//! finished; if another recording committed the same resource in between (the join is
//! stale), finishing fails with an error naming the resource.
//!
//! [`Context::record_into`]: crate::gpu::Context::record_into

use crate::error::{Error, Result};
use crate::gpu::image::{ImageInner, Subresources};
use crate::gpu::memory::BufferInner;
use crate::gpu::sync::{AccessSet, AccessType};
use crate::gpu::track::{AccessState, RangeTransition, Transition, merge_runs};
use crate::gpu::validation::lock;
use ash::vk;
use std::collections::HashMap;
use std::sync::Arc;

fn has_write(s: AccessSet) -> bool {
    s.iter().any(AccessType::is_write)
}

/// How a recording first met a resource.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Entry {
    /// Not used by this recording.
    Untouched,
    /// Only read so far, in one layout: the reads (joined at submission like one read).
    Reads(AccessSet),
    /// First accessed as `first` (a write, a layout change after reads, or a discard): the
    /// join waits for everything before and transitions to `first`'s layout.
    Access { first: AccessSet, discard: bool },
    /// Declared by the caller (an explicit barrier or a stated access): nothing to join,
    /// the caller's word stands.
    Declared,
    /// A caller's command buffer: joined at first use against the committed state whose
    /// version was `version`.
    Joined { version: u64 },
}

/// One buffer or image subresource, as this recording sees it.
#[derive(Clone, Copy, Debug)]
struct LocalSub {
    entry: Entry,
    state: AccessState,
}

impl LocalSub {
    const UNTOUCHED: LocalSub = LocalSub {
        entry: Entry::Untouched,
        state: AccessState {
            last: AccessSet::EMPTY,
            reads: AccessSet::EMPTY,
            wrote: false,
            layout: vk::ImageLayout::UNDEFINED,
        },
    };

    /// Applies `next` locally; returns the barrier needed inside the recording, if any.
    fn apply(&mut self, next: AccessSet, image: bool, discard: bool) -> Option<Transition> {
        let layout = if image {
            next.layout()
        } else {
            vk::ImageLayout::UNDEFINED
        };
        let read = !has_write(next) && !discard;
        match self.entry {
            Entry::Untouched => {
                self.entry = if read {
                    Entry::Reads(next)
                } else {
                    Entry::Access {
                        first: next,
                        discard,
                    }
                };
                // Reads accumulate (no barrier among them); a write or transition is the
                // first event of the local history.
                self.state = AccessState {
                    last: next,
                    reads: if has_write(next) {
                        AccessSet::EMPTY
                    } else {
                        next
                    },
                    wrote: !read,
                    layout,
                };
                None
            }
            Entry::Reads(reads) if read && self.state.layout == layout => {
                self.entry = Entry::Reads(reads | next);
                self.state.last = self.state.last | next;
                self.state.reads = self.state.reads | next;
                None
            }
            Entry::Reads(reads) => {
                self.entry = Entry::Access {
                    first: reads,
                    discard: false,
                };
                self.state.apply(next, image, discard)
            }
            _ => self.state.apply(next, image, discard),
        }
    }

    /// The state the caller declares (explicit barrier, untracked staging).
    fn declare(&mut self, state: AccessState) {
        if self.entry == Entry::Untouched {
            self.entry = Entry::Declared;
        }
        self.state = state;
    }

    /// For a caller's command buffer: joins an untouched subresource to the committed state
    /// now (so the join's barrier precedes the use).
    fn join_now(&mut self, committed: AccessState, version: u64) {
        if self.entry == Entry::Untouched {
            self.entry = Entry::Joined { version };
            self.state = committed;
        }
    }

    /// Joins this recording's use to the true state `g` (at submission); returns the
    /// prologue barrier, and leaves `g` as the state after the recording.
    fn resolve(&self, g: &mut AccessState, image: bool) -> Option<Transition> {
        match self.entry {
            Entry::Untouched => None,
            Entry::Reads(reads) => g.apply(reads, image, false),
            Entry::Access { first, discard } => {
                let old_layout = if discard {
                    vk::ImageLayout::UNDEFINED
                } else {
                    g.layout
                };
                let new_layout = if image {
                    first.layout()
                } else {
                    vk::ImageLayout::UNDEFINED
                };
                let prev = g.last | g.reads;
                let transition = image && old_layout != new_layout;
                let t = (!prev.is_empty() || transition).then_some(Transition {
                    prev,
                    next: first,
                    force_visible: g.wrote,
                    old_layout,
                    new_layout,
                });
                *g = self.state;
                t
            }
            Entry::Declared | Entry::Joined { .. } => {
                *g = self.state;
                None
            }
        }
    }
}

/// A buffer this recording uses.
struct LocalBuffer {
    inner: Arc<BufferInner>,
    sub: LocalSub,
}

/// An image this recording uses, per (mip, layer) as in `ImageState`.
struct LocalImage {
    inner: Arc<ImageInner>,
    mips: u32,
    subs: Vec<LocalSub>,
}

/// The join barriers of one submission, and how to undo the state changes if it fails.
pub(crate) struct Resolved {
    /// Barriers for the prologue: (buffer, transition) and (image, range transition).
    pub buffers: Vec<(Arc<BufferInner>, Transition)>,
    pub images: Vec<(Arc<ImageInner>, RangeTransition)>,
    undo_buffers: Vec<(Arc<BufferInner>, AccessState, u64)>,
    undo_images: Vec<(Arc<ImageInner>, crate::gpu::track::ImageState)>,
}

impl Resolved {
    /// Whether the prologue has no barrier to record.
    pub fn is_empty(&self) -> bool {
        self.buffers.is_empty() && self.images.is_empty()
    }

    /// Restores the tracked states as they were before [`LocalTracker::resolve`] (the
    /// submission failed: nothing it recorded runs).
    pub fn undo(self) {
        for (b, state, version) in self.undo_buffers {
            let mut g = lock(&b.state);
            g.state = state;
            g.version = version;
        }
        for (i, state) in self.undo_images {
            *lock(&i.state) = state;
        }
    }
}

/// Everything one recording does to the resources it uses (see the module docs).
#[derive(Default)]
pub(crate) struct LocalTracker {
    buffers: Vec<LocalBuffer>,
    images: Vec<LocalImage>,
    index: HashMap<usize, usize>,
    /// Whether resources are joined at first use (a caller's command buffer).
    join_at_first_use: bool,
}

impl LocalTracker {
    /// A tracker for a caller's command buffer: joins at first use, commits at finish.
    pub fn joining() -> Self {
        LocalTracker {
            join_at_first_use: true,
            ..Default::default()
        }
    }

    fn buffer(&mut self, inner: &Arc<BufferInner>) -> &mut LocalSub {
        let key = Arc::as_ptr(inner) as usize;
        let i = *self.index.entry(key).or_insert_with(|| {
            self.buffers.push(LocalBuffer {
                inner: inner.clone(),
                sub: LocalSub::UNTOUCHED,
            });
            self.buffers.len() - 1
        });
        let join = self.join_at_first_use;
        let sub = &mut self.buffers[i].sub;
        if join && sub.entry == Entry::Untouched {
            let g = lock(&inner.state);
            sub.join_now(g.state, g.version);
        }
        sub
    }

    fn image(&mut self, inner: &Arc<ImageInner>) -> &mut LocalImage {
        let key = Arc::as_ptr(inner) as usize;
        let i = *self.index.entry(key).or_insert_with(|| {
            let (mips, layers) = (inner.desc.mips, inner.desc.layers);
            self.images.push(LocalImage {
                inner: inner.clone(),
                mips,
                subs: vec![LocalSub::UNTOUCHED; (mips * layers) as usize],
            });
            self.images.len() - 1
        });
        &mut self.images[i]
    }

    /// Joins the untouched subresources of `range` now (a caller's command buffer).
    fn join_image_range(&mut self, inner: &Arc<ImageInner>, range: &Subresources) {
        if !self.join_at_first_use {
            return;
        }
        let img = self.image(inner);
        let g = lock(&inner.state);
        for (mip, layer) in range.iter() {
            let sub = &mut img.subs[(layer * img.mips + mip) as usize];
            sub.join_now(g.get(mip, layer), g.version());
        }
    }

    /// A declared use of a buffer; the barrier it needs inside this recording, if any.
    pub fn use_buffer(&mut self, inner: &Arc<BufferInner>, next: AccessSet) -> Option<Transition> {
        self.buffer(inner).apply(next, false, false)
    }

    /// A declared use of image subresources; the barriers they need inside this recording.
    pub fn use_image(
        &mut self,
        inner: &Arc<ImageInner>,
        range: &Subresources,
        next: AccessSet,
        discard: bool,
    ) -> Vec<RangeTransition> {
        self.join_image_range(inner, range);
        let img = self.image(inner);
        let mips = img.mips;
        merge_runs(range, |mip, layer| {
            img.subs[(layer * mips + mip) as usize].apply(next, true, discard)
        })
    }

    /// The caller states a buffer's state from here on (explicit barrier, staging).
    pub fn declare_buffer(&mut self, inner: &Arc<BufferInner>, f: impl FnOnce(&mut AccessState)) {
        let sub = self.buffer(inner);
        let mut s = sub.state;
        f(&mut s);
        sub.declare(s);
    }

    /// The caller states the state of image subresources from here on.
    pub fn declare_image(
        &mut self,
        inner: &Arc<ImageInner>,
        range: &Subresources,
        mut f: impl FnMut(&mut AccessState),
    ) {
        self.join_image_range(inner, range);
        let img = self.image(inner);
        for (mip, layer) in range.iter() {
            let sub = &mut img.subs[(layer * img.mips + mip) as usize];
            let mut s = sub.state;
            f(&mut s);
            sub.declare(s);
        }
    }

    /// Joins every entry to the true state, in submission order (the caller holds the queue
    /// lock): returns the prologue's barriers, and the tracked states become this recording's
    /// end states. Fails, changing nothing, if the recording reads image subresources that
    /// nothing has written (their layout is still UNDEFINED: the contents are garbage, and
    /// the transition would be one the validation layer warns about).
    pub fn resolve(&self, recorder: &str) -> Result<Resolved> {
        let out = self.resolve_unchecked();
        if let Some(name) = out.images.iter().find_map(|(img, t)| {
            let t = &t.transition;
            let reads_garbage = t.old_layout == vk::ImageLayout::UNDEFINED
                && !has_write(t.next)
                && t.new_layout != vk::ImageLayout::UNDEFINED
                && t.prev.is_empty();
            reads_garbage.then(|| img.name.clone())
        }) {
            out.undo();
            return Err(Error::InvalidArgument(format!(
                "recording '{recorder}' reads image '{name}' before anything wrote it (its \
                 contents are undefined): clear or upload it first, or declare its state with \
                 Image::assume_access"
            )));
        }
        Ok(out)
    }

    fn resolve_unchecked(&self) -> Resolved {
        let mut out = Resolved {
            buffers: Vec::new(),
            images: Vec::new(),
            undo_buffers: Vec::new(),
            undo_images: Vec::new(),
        };
        for b in &self.buffers {
            let mut g = lock(&b.inner.state);
            out.undo_buffers.push((b.inner.clone(), g.state, g.version));
            if let Some(t) = b.sub.resolve(&mut g.state, false) {
                out.buffers.push((b.inner.clone(), t));
            }
            g.version += 1;
        }
        for img in &self.images {
            let mut g = lock(&img.inner.state);
            out.undo_images.push((img.inner.clone(), g.clone()));
            let all = Subresources {
                base_mip: 0,
                mip_count: img.mips,
                base_layer: 0,
                layer_count: img.subs.len() as u32 / img.mips,
            };
            let transitions = merge_runs(&all, |mip, layer| {
                let mut s = g.get(mip, layer);
                let t = img.subs[(layer * img.mips + mip) as usize].resolve(&mut s, true);
                g.set(mip, layer, s);
                t
            });
            g.bump_version();
            out.images
                .extend(transitions.into_iter().map(|t| (img.inner.clone(), t)));
        }
        out
    }

    /// Commits the end states of a caller's command buffer (see the module docs); fails,
    /// changing nothing, if another recording committed a resource after this one joined it.
    pub fn commit_joined(&self, recorder: &str) -> Result<()> {
        let stale = |name: &str| {
            Error::InvalidArgument(format!(
                "recording '{recorder}' into a caller's command buffer used '{name}', whose \
                 tracked state another recording changed after this one first used it; \
                 record the two in the order they are submitted"
            ))
        };
        // Check everything first, so a refusal changes nothing.
        for b in &self.buffers {
            if let Entry::Joined { version } = b.sub.entry
                && lock(&b.inner.state).version != version
            {
                return Err(stale(&b.inner.name));
            }
        }
        for img in &self.images {
            let g = lock(&img.inner.state);
            if img
                .subs
                .iter()
                .any(|s| matches!(s.entry, Entry::Joined { version } if version != g.version()))
            {
                return Err(stale(&img.inner.name));
            }
        }
        let resolved = self.resolve_unchecked();
        debug_assert!(
            resolved.is_empty(),
            "joined recordings have no prologue barriers"
        );
        Ok(())
    }
}
