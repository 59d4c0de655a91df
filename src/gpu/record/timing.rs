//! Timestamp queries: one pair per named pass, read back as [`Timings`] once the work
//! has completed.

use super::Recorder;
use crate::error::{Result, VkResultExt};
use crate::gpu::context::Shared;
use ash::vk;

/// GPU time of one named pass.
#[derive(Clone, Debug, serde::Serialize)]
pub struct PassTiming {
    /// The name given to [`Recorder::begin_pass`].
    pub name: String,
    /// Nesting depth (0 = outermost).
    pub depth: usize,
    /// GPU time between the pass's two timestamps, in milliseconds.
    pub ms: f64,
}

/// GPU times of the passes of one submission, from timestamp queries.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct Timings {
    /// The timed passes, in the order they were opened.
    pub passes: Vec<PassTiming>,
    /// Passes that got no timing: beyond the query capacity (`MAX_PASSES`), or no
    /// timestamps on this queue.
    pub untimed: Vec<String>,
}

impl Timings {
    /// Milliseconds of the passes called `name`, summed (a recording may open a pass of the
    /// same name more than once: e.g. one `btf shade` per BTF of a frame); None when none is.
    pub fn get(&self, name: &str) -> Option<f64> {
        self.passes
            .iter()
            .filter(|p| p.name == name)
            .map(|p| p.ms)
            .reduce(|a, b| a + b)
    }

    /// Sum over all outermost passes; NaN when any pass went untimed (no timestamps on the
    /// queue, or more passes than [`MAX_PASSES`]): a sum that leaves passes out would pass for
    /// a faster frame.
    pub fn total_ms(&self) -> f64 {
        if !self.untimed.is_empty() {
            return f64::NAN;
        }
        self.passes
            .iter()
            .filter(|p| p.depth == 0)
            .map(|p| p.ms)
            .sum()
    }
}

pub(super) struct Pass {
    pub(super) name: String,
    pub(super) depth: usize,
    pub(super) begin: Option<u32>,
    pub(super) end: Option<u32>,
}

/// Maximum number of timestamped passes per recorder.
pub const MAX_PASSES: u32 = 128;

/// Timestamp queries of one recording.
pub(super) struct Queries {
    pub(super) pool: vk::QueryPool,
    pub(super) used: u32,
    pub(super) passes: Vec<Pass>,
}

impl Queries {
    /// Reads the timings (the work has completed).
    pub(super) fn collect(&self, shared: &Shared) -> Result<Timings> {
        let mut timings = Timings::default();
        if self.used == 0 {
            timings.untimed = self.passes.iter().map(|p| p.name.clone()).collect();
            return Ok(timings);
        }
        let mut raw = vec![0u64; self.used as usize];
        // SAFETY: queries 0..used were written by the completed submission.
        unsafe {
            shared.device.get_query_pool_results(
                self.pool,
                0,
                &mut raw,
                vk::QueryResultFlags::TYPE_64 | vk::QueryResultFlags::WAIT,
            )
        }
        .vk("vkGetQueryPoolResults")?;
        let limits = &shared.info.limits;
        let mask = if limits.timestamp_valid_bits >= 64 {
            u64::MAX
        } else {
            (1u64 << limits.timestamp_valid_bits) - 1
        };
        for p in &self.passes {
            let (Some(b), Some(e)) = (p.begin, p.end) else {
                timings.untimed.push(p.name.clone());
                continue;
            };
            let ticks = raw[e as usize].wrapping_sub(raw[b as usize]) & mask;
            timings.passes.push(PassTiming {
                name: p.name.clone(),
                depth: p.depth,
                ms: ticks as f64 * limits.timestamp_period_ns as f64 * 1e-6,
            });
        }
        Ok(timings)
    }
}

impl Recorder {
    /// Creates the timestamp pool and resets it in the command buffer (when the queue has
    /// timestamps).
    pub(super) fn start_queries(&mut self) -> Result<()> {
        if self.shared.info.limits.timestamp_valid_bits == 0 {
            return Ok(());
        }
        self.queries.pool = match self.shared.take_query_pool() {
            Some(pool) => pool,
            None => {
                let qinfo = vk::QueryPoolCreateInfo::default()
                    .query_type(vk::QueryType::TIMESTAMP)
                    .query_count(2 * MAX_PASSES);
                // SAFETY: valid device and create info.
                let pool = unsafe { self.shared.device.create_query_pool(&qinfo, None) }
                    .vk("vkCreateQueryPool")?;
                crate::gpu::recycle::Counters::bump(&self.shared.counters.query_pools);
                pool
            }
        };
        // SAFETY: recording; the pool is new, or pooled after its last use completed; every
        // query is reset before this recording writes it.
        unsafe {
            self.shared
                .device
                .cmd_reset_query_pool(self.cmd, self.queries.pool, 0, 2 * MAX_PASSES)
        };
        Ok(())
    }

    pub(super) fn timestamp(&mut self, stage: vk::PipelineStageFlags2) -> Option<u32> {
        if self.queries.pool == vk::QueryPool::null() || self.queries.used >= 2 * MAX_PASSES {
            return None;
        }
        let q = self.queries.used;
        self.queries.used += 1;
        // SAFETY: recording; query `q` was reset at the start of this command buffer.
        unsafe {
            self.device()
                .cmd_write_timestamp2(self.cmd, stage, self.queries.pool, q)
        };
        Some(q)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pass(name: &str, depth: usize, ms: f64) -> PassTiming {
        PassTiming {
            name: name.into(),
            depth,
            ms,
        }
    }

    #[test]
    fn the_total_sums_outermost_passes_and_is_nan_when_one_went_untimed() {
        let mut t = Timings {
            passes: vec![
                pass("a", 0, 1.5),
                pass("a.inner", 1, 1.0),
                pass("b", 0, 2.0),
            ],
            untimed: Vec::new(),
        };
        assert_eq!(t.total_ms(), 3.5);
        assert_eq!(t.get("a"), Some(1.5));
        assert_eq!(t.get("c"), None);
        t.untimed.push("c".into());
        assert!(t.total_ms().is_nan());
    }
}
