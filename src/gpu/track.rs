//! State tracking: each buffer, and each (mip, layer) of an image, remembers how it was last
//! accessed and in which layout, so a declared use (`Recorder::use_buffer`,
//! `Recorder::use_image`, tracked dispatches) yields the minimal barrier.
//!
//! Rules, per buffer or subresource, for a next access `next`:
//! - a write, or a layout change: wait for every access since the last write (and the write),
//!   then `next` becomes the last access;
//! - a read of the current layout after reads only: no barrier (the reads accumulate, so a
//!   later write waits for all of them);
//! - a read after a write (or a layout transition): a barrier from the write to the reads not
//!   yet made visible; reads already covered need nothing.
//!
//! This is the state of each resource as of the last *submitted* recording. A recording tracks
//! its own uses apart from it and joins them to it when it is submitted (see
//! `record::local`), so recordings may be submitted in any order, or dropped.

use super::image::Subresources;
use super::sync::{AccessSet, AccessType};
use ash::vk;

/// The tracked state of one buffer or image subresource.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct AccessState {
    /// The accesses a later write (or transition) must wait for as its source, together
    /// with `reads`.
    pub last: AccessSet,
    /// Reads since `last` that are already ordered (and made visible) after it.
    pub reads: AccessSet,
    /// Whether `last` wrote (a write access or a layout transition).
    pub wrote: bool,
    /// The layout (images only; UNDEFINED for buffers and fresh images).
    pub layout: vk::ImageLayout,
}

/// One dependency the tracker wants recorded.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Transition {
    /// The accesses to wait for.
    pub prev: AccessSet,
    /// The accesses that wait.
    pub next: AccessSet,
    /// Force visibility to `next` (the source wrote only through a layout transition).
    pub force_visible: bool,
    /// The layout before (UNDEFINED for buffers, or to discard an image's contents).
    pub old_layout: vk::ImageLayout,
    /// The layout after (UNDEFINED for buffers).
    pub new_layout: vk::ImageLayout,
}

fn has_write(s: AccessSet) -> bool {
    s.iter().any(AccessType::is_write)
}

impl AccessState {
    /// The state after `access` with nothing to wait for (declared by the caller).
    pub fn after(access: AccessSet) -> Self {
        AccessState {
            last: access,
            reads: AccessSet::EMPTY,
            wrote: has_write(access),
            layout: access.layout(),
        }
    }

    /// Applies `next`; returns the dependency needed before it, if any. `image` selects the
    /// layout rules.
    pub fn apply(&mut self, next: AccessSet, image: bool, discard: bool) -> Option<Transition> {
        let new_layout = if image {
            next.layout()
        } else {
            vk::ImageLayout::UNDEFINED
        };
        let old_layout = if discard {
            vk::ImageLayout::UNDEFINED
        } else {
            self.layout
        };
        let layout_change = image && old_layout != new_layout;
        if has_write(next) || layout_change || discard {
            let prev = self.last | self.reads;
            // A write after an earlier write that was made visible only to reads in between
            // still needs that write visible to it (synchronization validation reports a
            // write-after-write hazard otherwise): the chain carries the memory dependency.
            let after_write = self.wrote;
            // After a transition to a read-only access, those reads already see it.
            let reads = if has_write(next) {
                AccessSet::EMPTY
            } else {
                next
            };
            *self = AccessState {
                last: next,
                reads,
                wrote: true,
                layout: new_layout,
            };
            // A first use of a buffer, or a discard with no earlier access, needs nothing.
            if prev.is_empty() && !layout_change {
                return None;
            }
            return Some(Transition {
                prev,
                next,
                force_visible: after_write && has_write(next),
                old_layout,
                new_layout,
            });
        }
        // Read-only, same layout.
        if !self.wrote {
            self.last = self.last | next;
            self.reads = self.reads | next;
            return None;
        }
        let missing = AccessSet::from_bits(next.bits() & !self.reads.bits());
        if missing.is_empty() {
            return None;
        }
        let t = Transition {
            prev: self.last,
            next: missing,
            force_visible: true,
            old_layout: self.layout,
            new_layout: self.layout,
        };
        // Later reads chain through the reads so far, and a later write waits for them all.
        // The write stays in `last`, so that a later write or layout transition names it in
        // its source access scope again: a declared read need not be followed by any command
        // that reads (`use_image` declares, the GPU may never read), and then synchronization
        // validation does not accept the execution chain through the read barrier as
        // ordering the write before a layout transition (SYNC-HAZARD-WRITE-AFTER-WRITE,
        // found by tests/fuzz_api.rs; see tests/safe_api.rs). Naming an already available
        // write again costs nothing on the GPU.
        let written =
            (self.last.iter().filter(|a| a.is_write())).fold(AccessSet::EMPTY, |s, a| s | a);
        self.reads = self.reads | missing;
        self.last = self.reads | written;
        Some(t)
    }
}

/// Tracked state of a buffer.
pub type BufferState = AccessState;

/// A buffer's tracked state and how many submissions have changed it (recordings into a
/// caller's command buffer check that nothing changed it between their join and commit).
#[derive(Clone, Copy, Debug, Default)]
pub struct BufferTrack {
    /// The state after the last submitted recording.
    pub state: BufferState,
    /// Bumped by every commit.
    pub version: u64,
}

impl BufferState {
    /// [`AccessState::apply`] for a buffer: no layouts, nothing to discard.
    pub fn apply_buffer(&mut self, next: AccessSet) -> Option<Transition> {
        self.apply(next, false, false)
    }
}

/// Tracked state of every (mip, layer) of an image, indexed `layer * mips + mip`.
#[derive(Clone, Debug)]
pub struct ImageState {
    mips: u32,
    layers: u32,
    subs: Vec<AccessState>,
    /// Bumped by every commit (see [`BufferTrack::version`]).
    version: u64,
}

/// A transition for a range of subresources.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RangeTransition {
    /// The subresources it covers.
    pub range: Subresources,
    /// The dependency they need.
    pub transition: Transition,
}

impl ImageState {
    /// Every subresource of a `mips` x `layers` image unused (UNDEFINED layout).
    pub fn new(mips: u32, layers: u32) -> Self {
        ImageState {
            mips,
            layers,
            subs: vec![AccessState::default(); (mips * layers) as usize],
            version: 0,
        }
    }

    /// How many commits have changed this image's state.
    pub fn version(&self) -> u64 {
        self.version
    }

    /// Marks a commit.
    pub fn bump_version(&mut self) {
        self.version += 1;
    }

    /// The state of one subresource.
    pub fn get(&self, mip: u32, layer: u32) -> AccessState {
        self.subs[(layer * self.mips + mip) as usize]
    }

    /// Replaces the state of one subresource.
    pub fn set(&mut self, mip: u32, layer: u32, s: AccessState) {
        self.subs[(layer * self.mips + mip) as usize] = s;
    }

    /// Declares `range` last accessed as `access` (outside tracking), with nothing to wait for.
    pub fn assume(&mut self, range: &Subresources, access: AccessSet) {
        for (mip, layer) in range.iter() {
            self.subs[(layer * self.mips + mip) as usize] = AccessState::after(access);
        }
        self.version += 1;
    }

    /// Applies `next` to `range` (checked by the caller); returns the transitions needed,
    /// merged: per mip, runs of consecutive layers with the same transition become one
    /// range, then equal layer runs of consecutive mips merge.
    pub fn apply(
        &mut self,
        range: &Subresources,
        next: AccessSet,
        discard: bool,
    ) -> Vec<RangeTransition> {
        // Every public entry point checks ranges against the image (Subresources::check).
        assert!(
            range.base_mip + range.mip_count <= self.mips
                && range.base_layer + range.layer_count <= self.layers,
            "unchecked subresource range {range:?}"
        );
        let mips = self.mips;
        merge_runs(range, |mip, layer| {
            self.subs[(layer * mips + mip) as usize].apply(next, true, discard)
        })
    }
}

/// Collects per-subresource transitions over `range` into merged ranges: per mip, runs of
/// consecutive layers with the same transition become one range, then equal layer runs of
/// consecutive mips merge. `f(mip, layer)` is called once per subresource, mip-major.
pub fn merge_runs(
    range: &Subresources,
    mut f: impl FnMut(u32, u32) -> Option<Transition>,
) -> Vec<RangeTransition> {
    // Per mip: runs of layers.
    let mut per_mip: Vec<Vec<RangeTransition>> = Vec::new();
    for mip in range.base_mip..range.base_mip + range.mip_count {
        let mut runs: Vec<RangeTransition> = Vec::new();
        for layer in range.base_layer..range.base_layer + range.layer_count {
            let Some(t) = f(mip, layer) else {
                continue;
            };
            match runs.last_mut() {
                Some(r)
                    if r.transition == t && r.range.base_layer + r.range.layer_count == layer =>
                {
                    r.range.layer_count += 1
                }
                _ => runs.push(RangeTransition {
                    range: Subresources {
                        base_mip: mip,
                        mip_count: 1,
                        base_layer: layer,
                        layer_count: 1,
                    },
                    transition: t,
                }),
            }
        }
        per_mip.push(runs);
    }
    // Merge identical runs of consecutive mips.
    let mut out: Vec<RangeTransition> = Vec::new();
    for runs in per_mip {
        for r in runs {
            let merged = out.iter_mut().rev().find(|o| {
                o.transition == r.transition
                    && o.range.base_layer == r.range.base_layer
                    && o.range.layer_count == r.range.layer_count
                    && o.range.base_mip + o.range.mip_count == r.range.base_mip
            });
            match merged {
                Some(o) => o.range.mip_count += 1,
                None => out.push(r),
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use AccessType as A;

    #[test]
    fn read_after_read_needs_no_barrier_and_write_waits_for_all_reads() {
        let mut s = BufferState::default();
        assert_eq!(s.apply_buffer(A::TransferWrite.into()), None, "first use");
        let t = s.apply_buffer(A::ComputeShaderReadOther.into()).unwrap();
        assert_eq!(t.prev, A::TransferWrite.into());
        assert_eq!(s.apply_buffer(A::ComputeShaderReadOther.into()), None);
        let t = s.apply_buffer(A::VertexBuffer.into()).unwrap();
        assert_eq!(t.next, A::VertexBuffer.into(), "only the new read");
        assert_eq!(
            t.prev,
            A::ComputeShaderReadOther | A::TransferWrite,
            "chained through the reads, the write named again"
        );
        let t = s.apply_buffer(A::ComputeShaderWrite.into()).unwrap();
        assert!(t.prev.contains(A::ComputeShaderReadOther));
        assert!(t.prev.contains(A::VertexBuffer));
        // Available since the first read's barrier, but a declared read may have no command
        // behind it, and synchronization validation then wants the write in the source
        // scope of the next write or transition (see AccessState::apply).
        assert!(
            t.prev.contains(A::TransferWrite),
            "the last write stays a source"
        );
    }

    #[test]
    fn image_layout_changes_are_transitions_even_between_reads() {
        let mut s = ImageState::new(1, 1);
        let all = Subresources {
            base_mip: 0,
            mip_count: 1,
            base_layer: 0,
            layer_count: 1,
        };
        let t = s.apply(&all, A::TransferWrite.into(), false);
        assert_eq!(t.len(), 1);
        assert_eq!(t[0].transition.old_layout, vk::ImageLayout::UNDEFINED);
        let t = s.apply(&all, A::ComputeShaderReadSampledImage.into(), false);
        assert_eq!(
            t[0].transition.new_layout,
            vk::ImageLayout::SHADER_READ_ONLY_OPTIMAL
        );
        let again = s.apply(&all, A::ComputeShaderReadSampledImage.into(), false);
        assert!(
            again.is_empty(),
            "the transition's reads need no second barrier"
        );
        let t = s.apply(&all, A::TransferRead.into(), false);
        assert_eq!(t.len(), 1, "read -> read in another layout transitions");
        assert_eq!(
            t[0].transition.old_layout,
            vk::ImageLayout::SHADER_READ_ONLY_OPTIMAL
        );
    }

    /// Random sequences on a 4-mip, 3-layer image: the merged ranges cover exactly the
    /// subresources a naive per-subresource model says need a barrier, with its transition.
    #[test]
    fn merged_ranges_match_a_per_subresource_model() {
        let accesses = [
            AccessSet::from(A::TransferWrite),
            A::TransferRead.into(),
            A::ComputeShaderReadSampledImage.into(),
            A::ComputeShaderWrite.into(),
            A::ComputeShaderReadOther.into(),
            A::ComputeShaderReadOther | A::ComputeShaderWrite,
        ];
        let mut rng = 0x1234_5678u64;
        let mut next = |n: u32| {
            rng ^= rng << 13;
            rng ^= rng >> 7;
            rng ^= rng << 17;
            (rng % n as u64) as u32
        };
        let (mips, layers) = (4, 3);
        let mut tracked = ImageState::new(mips, layers);
        let mut naive = vec![AccessState::default(); (mips * layers) as usize];
        for _ in 0..2000 {
            let base_mip = next(mips);
            let mip_count = 1 + next(mips - base_mip);
            let base_layer = next(layers);
            let layer_count = 1 + next(layers - base_layer);
            let range = Subresources {
                base_mip,
                mip_count,
                base_layer,
                layer_count,
            };
            let access = accesses[next(accesses.len() as u32) as usize];
            let discard = next(8) == 0;
            let got = tracked.apply(&range, access, discard);
            let mut covered = vec![None; (mips * layers) as usize];
            for r in &got {
                for l in r.range.base_layer..r.range.base_layer + r.range.layer_count {
                    for m in r.range.base_mip..r.range.base_mip + r.range.mip_count {
                        let i = (l * mips + m) as usize;
                        assert!(covered[i].is_none(), "subresource covered twice");
                        covered[i] = Some(r.transition);
                    }
                }
            }
            for l in 0..layers {
                for m in 0..mips {
                    let i = (l * mips + m) as usize;
                    let inside = (base_layer..base_layer + layer_count).contains(&l)
                        && (base_mip..base_mip + mip_count).contains(&m);
                    let want = if inside {
                        naive[i].apply(access, true, discard)
                    } else {
                        None
                    };
                    assert_eq!(covered[i], want, "mip {m} layer {l}");
                    assert_eq!(tracked.get(m, l), naive[i]);
                }
            }
        }
    }
}
