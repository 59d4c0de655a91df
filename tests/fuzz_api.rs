//! An API fuzzer: random sequences of safe calls on two validated contexts from two threads
//! at once — create and drop buffers and images, bind them (sometimes across contexts),
//! record copies, fills, uploads, clears, readbacks, declared uses and tracked dispatches into
//! several open recorders, then submit them in any order, drop them unsubmitted, wait, drop
//! or forget submissions, and write host-visible buffers while work is in flight.
//!
//! Any validation message (synchronization validation on), any panic, and any `Err` that the
//! step does not document fails the test, naming the seed and the step. Allowed errors: a
//! resource of the other context (`WrongContext`), submitting a recording that reads an
//! image nothing has written, and reading a readback whose recording was dropped.
//!
//! CI runs `STEPS` steps per thread with a fixed seed; a longer run:
//! `VKSHADE_FUZZ_STEPS=200000 VKSHADE_FUZZ_SEED=7 cargo test --release --test fuzz_api`.
//!
//! What it found, each now a named test in tests/safe_api.rs: a read of an image nothing
//! had written transitioned it from UNDEFINED to a read-only layout (a best-practices
//! warning, and garbage read); such a submission is now refused.

mod common;

use ash::vk;
use common::{assert_clean, context};
use std::sync::{Arc, Mutex};
use vkshade::gpu::{
    AccessSet, AccessType as A, BindGroup, Buffer, BufferDesc, ComputePipeline, Context, Image,
    ImageDesc, ImageRegion, Readback, Recorder, Resource, Submission,
};
use vkshade::shaders::spirv;

/// Steps per thread in CI.
const STEPS: u64 = 5000;
/// Side of every image (RGBA32F).
const W: u32 = 16;

struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        // xorshift64*
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_f491_4f6c_dd1d)
    }
    fn below(&mut self, n: usize) -> usize {
        (self.next() % n.max(1) as u64) as usize
    }
    fn chance(&mut self, one_in: u64) -> bool {
        self.next().is_multiple_of(one_in)
    }
}

/// What both threads share: two contexts, their pipelines, and pools of resources.
struct World {
    ctx: [Context; 2],
    scale: [ComputePipeline; 2],
    pingpong: [ComputePipeline; 2],
    buffers: [Mutex<Vec<Arc<Buffer>>>; 2],
    images: [Mutex<Vec<Arc<Image>>>; 2],
}

/// What one thread holds.
#[derive(Default)]
struct Local {
    recorders: Vec<(usize, Recorder, Vec<Readback>)>,
    submissions: Vec<Submission>,
    readbacks: Vec<Readback>,
    orphans: Vec<Readback>,
    binds: Vec<(usize, bool, BindGroup, u32)>,
    forgot: bool,
    /// Per step label: (succeeded, refused with a documented error).
    counts: std::collections::BTreeMap<&'static str, (u64, u64)>,
}

fn pick<T>(rng: &mut Rng, pool: &Mutex<Vec<Arc<T>>>) -> Option<Arc<T>> {
    let pool = pool.lock().unwrap();
    (!pool.is_empty()).then(|| pool[rng.below(pool.len())].clone())
}

/// A context index: usually `own`, sometimes the other one (a cross-context use).
fn maybe_other(rng: &mut Rng, own: usize) -> usize {
    if rng.chance(10) { 1 - own } else { own }
}

fn scale_push(n: u32) -> Vec<u8> {
    [2.0f32.to_le_bytes(), 1.0f32.to_le_bytes(), n.to_le_bytes()].concat()
}

fn pingpong_push() -> Vec<u8> {
    [
        W.to_le_bytes(),
        W.to_le_bytes(),
        0.5f32.to_le_bytes(),
        0.25f32.to_le_bytes(),
    ]
    .concat()
}

/// Whether `e` is an error the step may return: cross-context use, a resource bound twice,
/// or a documented refusal.
fn allowed(e: &vkshade::Error, cross: bool) -> bool {
    match e {
        vkshade::Error::WrongContext { .. } => cross,
        // Submitting a recording that reads an image nothing wrote.
        vkshade::Error::InvalidArgument(m) => m.contains("before anything wrote it"),
        _ => false,
    }
}

/// One random step. Returns a label (for failure messages) and the result.
fn step(
    w: &World,
    l: &mut Local,
    rng: &mut Rng,
    own: usize,
) -> (&'static str, bool, vkshade::Result<()>) {
    let c = maybe_other(rng, own);
    let cross = c != own;
    match rng.below(20) {
        0 => {
            let size = 256 * (1 + rng.below(16) as u64);
            let desc = if rng.chance(3) {
                BufferDesc::upload(size)
            } else {
                BufferDesc::storage(size)
                    .usage(vk::BufferUsageFlags::TRANSFER_DST | vk::BufferUsageFlags::TRANSFER_SRC)
            };
            let r = Buffer::new(&w.ctx[own], "fuzz buffer", desc).map(|b| {
                w.buffers[own].lock().unwrap().push(Arc::new(b));
            });
            ("create buffer", false, r)
        }
        1 => {
            let desc = ImageDesc::d2(vk::Format::R32G32B32A32_SFLOAT, [W, W]).usage(
                vk::ImageUsageFlags::STORAGE
                    | vk::ImageUsageFlags::SAMPLED
                    | vk::ImageUsageFlags::TRANSFER_SRC
                    | vk::ImageUsageFlags::TRANSFER_DST,
            );
            let r = Image::new(&w.ctx[own], "fuzz image", desc).map(|i| {
                w.images[own].lock().unwrap().push(Arc::new(i));
            });
            ("create image", false, r)
        }
        2 => {
            let mut pool = w.buffers[own].lock().unwrap();
            if pool.len() > 2 {
                let i = rng.below(pool.len());
                pool.swap_remove(i);
            }
            let mut pool = w.images[own].lock().unwrap();
            if pool.len() > 2 {
                let i = rng.below(pool.len());
                pool.swap_remove(i);
            }
            ("drop resources", false, Ok(()))
        }
        3 => {
            // Bind the scale pipeline of `own` to buffers of `c`.
            let (Some(src), Some(dst)) = (pick(rng, &w.buffers[c]), pick(rng, &w.buffers[c]))
            else {
                return ("bind buffers", cross, Ok(()));
            };
            if Arc::ptr_eq(&src, &dst) || dst.desc().placement != BufferDesc::storage(4).placement {
                return ("bind buffers", cross, Ok(()));
            }
            let n = (src.size().min(dst.size()) / 4) as u32;
            let r = w.scale[own]
                .bind(&[
                    ("src", Resource::Buffer(&src)),
                    ("dst", Resource::Buffer(&dst)),
                ])
                .map(|b| l.binds.push((own, false, b, n)));
            ("bind buffers", cross, r)
        }
        4 => {
            let (Some(src), Some(dst)) = (pick(rng, &w.images[c]), pick(rng, &w.images[c])) else {
                return ("bind images", cross, Ok(()));
            };
            if Arc::ptr_eq(&src, &dst) {
                return ("bind images", cross, Ok(()));
            }
            let r = w.pingpong[own]
                .bind(&[
                    ("src", Resource::StorageImage((&*src).into())),
                    ("dst", Resource::StorageImage((&*dst).into())),
                ])
                .map(|b| l.binds.push((own, true, b, 0)));
            ("bind images", cross, r)
        }
        5 => {
            if l.recorders.len() < 4 {
                let r = w.ctx[own]
                    .recorder("fuzz")
                    .map(|rec| l.recorders.push((own, rec, Vec::new())));
                return ("new recorder", false, r);
            }
            ("new recorder", false, Ok(()))
        }
        6..=12 => record(w, l, rng, own),
        13 | 14 => {
            if l.recorders.is_empty() {
                return ("submit", false, Ok(()));
            }
            let i = rng.below(l.recorders.len());
            let (_, rec, rbs) = l.recorders.swap_remove(i);
            let r = rec.submit().map(|s| {
                l.submissions.push(s);
                l.readbacks.extend(rbs);
            });
            ("submit", false, r)
        }
        15 => {
            if !l.recorders.is_empty() && rng.chance(3) {
                let i = rng.below(l.recorders.len());
                let (_, rec, rbs) = l.recorders.swap_remove(i);
                drop(rec);
                l.orphans.extend(rbs);
            }
            ("drop recorder", false, Ok(()))
        }
        16 => {
            if l.submissions.is_empty() {
                return ("wait", false, Ok(()));
            }
            let i = rng.below(l.submissions.len());
            let s = l.submissions.swap_remove(i);
            let r = if rng.chance(2) {
                s.wait().map(|_| ())
            } else if rng.chance(200) {
                std::mem::forget(s);
                l.forgot = true;
                Ok(())
            } else {
                drop(s);
                Ok(())
            };
            ("wait, drop or forget a submission", false, r)
        }
        17 => {
            if l.readbacks.is_empty() {
                return ("read a readback", false, Ok(()));
            }
            let i = rng.below(l.readbacks.len());
            let rb = l.readbacks.swap_remove(i);
            ("read a readback", false, rb.to_vec::<u8>().map(|_| ()))
        }
        18 => {
            // A dropped recording's readback is an error, not a wait forever.
            let r = match l.orphans.pop() {
                Some(rb) => match rb.to_vec::<u8>() {
                    Err(vkshade::Error::InvalidArgument(_)) => Ok(()),
                    Err(e) => Err(e),
                    Ok(_) => panic!("a readback of a dropped recording returned data"),
                },
                None => Ok(()),
            };
            ("read an orphaned readback", false, r)
        }
        _ => {
            // Host writes wait for in-flight work that uses the buffer.
            let r = match pick(rng, &w.buffers[own]) {
                Some(b) if b.placement() == BufferDesc::upload(4).placement => {
                    b.write(0, &[rng.next() as u32; 16])
                }
                _ => Ok(()),
            };
            ("host write", false, r)
        }
    }
}

/// Records one random command into a random open recorder.
fn record(
    w: &World,
    l: &mut Local,
    rng: &mut Rng,
    _own: usize,
) -> (&'static str, bool, vkshade::Result<()>) {
    if l.recorders.is_empty() {
        return ("record", false, Ok(()));
    }
    let ri = rng.below(l.recorders.len());
    let rc = l.recorders[ri].0;
    let c = maybe_other(rng, rc);
    let cross = c != rc;
    let rec = &mut l.recorders[ri].1;
    let accesses: [AccessSet; 5] = [
        A::TransferRead.into(),
        A::TransferWrite.into(),
        A::ComputeShaderReadOther.into(),
        A::ComputeShaderWrite.into(),
        A::ComputeShaderReadSampledImage.into(),
    ];
    let transfer_buffer = |b: &Buffer| {
        b.usage()
            .contains(vk::BufferUsageFlags::TRANSFER_DST | vk::BufferUsageFlags::TRANSFER_SRC)
    };
    match rng.below(12) {
        0 => {
            let (Some(a), Some(b)) = (pick(rng, &w.buffers[c]), pick(rng, &w.buffers[c])) else {
                return ("copy buffer", cross, Ok(()));
            };
            if Arc::ptr_eq(&a, &b) || !transfer_buffer(&a) || !transfer_buffer(&b) {
                return ("copy buffer", cross, Ok(()));
            }
            let size = a.size().min(b.size()) / 2;
            (
                "copy buffer",
                cross,
                rec.copy_buffer(&a, 0, &b, size / 4 * 4, size / 4 * 4),
            )
        }
        1 => match pick(rng, &w.buffers[c]) {
            Some(b) if transfer_buffer(&b) => {
                ("fill buffer", cross, rec.fill_buffer(&b, rng.next() as u32))
            }
            _ => ("fill buffer", cross, Ok(())),
        },
        2 => match pick(rng, &w.buffers[c]) {
            Some(b) if transfer_buffer(&b) => (
                "upload",
                cross,
                rec.upload(&b, 0, &vec![1.5f32; (b.size() / 8) as usize]),
            ),
            _ => ("upload", cross, Ok(())),
        },
        3 => match pick(rng, &w.buffers[c]) {
            Some(b) if transfer_buffer(&b) => {
                let r = rec.read_back_range(&b, 0, 64);
                (
                    "read back buffer",
                    cross,
                    r.map(|rb| l.recorders[ri].2.push(rb)),
                )
            }
            _ => ("read back buffer", cross, Ok(())),
        },
        4 => match pick(rng, &w.images[c]) {
            Some(i) => ("clear image", cross, rec.clear_image(&i, i.all(), [0.5; 4])),
            None => ("clear image", cross, Ok(())),
        },
        5 => match pick(rng, &w.images[c]) {
            Some(i) => {
                let r = rec.read_back_image(&i, ImageRegion::whole(i.desc()));
                (
                    "read back image",
                    cross,
                    r.map(|rb| l.recorders[ri].2.push(rb)),
                )
            }
            None => ("read back image", cross, Ok(())),
        },
        6 => {
            let (Some(a), Some(b)) = (pick(rng, &w.images[c]), pick(rng, &w.images[c])) else {
                return ("copy image", cross, Ok(()));
            };
            if Arc::ptr_eq(&a, &b) {
                return ("copy image", cross, Ok(()));
            }
            let region = ImageRegion::whole(a.desc());
            ("copy image", cross, rec.copy_image(&a, region, &b, region))
        }
        7 => match pick(rng, &w.images[c]) {
            Some(i) => {
                let access = accesses[rng.below(accesses.len())];
                ("use image", cross, rec.use_image(&i, i.all(), access))
            }
            None => ("use image", cross, Ok(())),
        },
        8 => match pick(rng, &w.buffers[c]) {
            Some(b) if b.usage().contains(vk::BufferUsageFlags::STORAGE_BUFFER) => {
                let access = accesses[rng.below(4)];
                ("use buffer", cross, rec.use_buffer(&b, access))
            }
            _ => ("use buffer", cross, Ok(())),
        },
        9 => {
            rec.begin_pass("fuzz pass");
            ("begin pass", false, Ok(()))
        }
        10 => {
            rec.end_pass();
            ("end pass", false, Ok(()))
        }
        _ => {
            // A tracked dispatch with a bind group of this thread (maybe another context's).
            let candidates: Vec<usize> =
                (0..l.binds.len()).filter(|&i| l.binds[i].0 == c).collect();
            if candidates.is_empty() {
                return ("dispatch", cross, Ok(()));
            }
            let (bc, images, bind, n) = &l.binds[candidates[rng.below(candidates.len())]];
            let r = if *images {
                rec.dispatch_invocations_tracked(
                    &w.pingpong[*bc],
                    bind,
                    &pingpong_push(),
                    [W, W, 1],
                )
            } else {
                rec.dispatch_invocations_tracked(&w.scale[*bc], bind, &scale_push(*n), [*n, 1, 1])
            };
            ("dispatch", cross, r)
        }
    }
}

type Counts = std::collections::BTreeMap<&'static str, (u64, u64)>;

/// Runs `steps` random steps; returns whether a submission was forgotten, and the counts.
fn run_thread(w: &World, seed: u64, thread: usize, steps: u64) -> (bool, Counts) {
    let mut rng = Rng(seed.wrapping_mul(0x9e37_79b9_7f4a_7c15) ^ (thread as u64 + 1));
    let mut l = Local::default();
    let own = thread % 2;
    for i in 0..steps {
        let own = if rng.chance(4) { 1 - own } else { own };
        let (label, cross, result) = step(w, &mut l, &mut rng, own);
        let count = l.counts.entry(label).or_default();
        match result {
            Ok(()) => count.0 += 1,
            Err(e) if allowed(&e, cross) => count.1 += 1,
            Err(e) => {
                panic!("seed {seed} thread {thread} step {i} ({label}): undocumented error: {e}")
            }
        }
        if std::env::var("VKSHADE_FUZZ_TRACE").is_ok() {
            eprintln!("t{thread} {i} c{own} {label}");
        }
        if i % 64 == 0 || std::env::var("VKSHADE_FUZZ_TRACE").is_ok() {
            for ctx in &w.ctx {
                let m = ctx.messages().take();
                if !m.is_empty() {
                    eprintln!("seed {seed} thread {thread}: messages by step {i} ({label})");
                    assert_clean(&m);
                }
            }
        }
    }
    // Finish: submit or drop what is open, wait for everything.
    for (k, (_, rec, rbs)) in std::mem::take(&mut l.recorders).into_iter().enumerate() {
        if k % 2 == 0 {
            match rec.submit() {
                Ok(s) => {
                    l.submissions.push(s);
                    l.readbacks.extend(rbs);
                }
                Err(e) if allowed(&e, false) => {}
                Err(e) => panic!("seed {seed} thread {thread}: final submit: {e}"),
            }
        }
    }
    for s in l.submissions.drain(..) {
        s.wait().expect("final wait");
    }
    for rb in l.readbacks.drain(..) {
        rb.to_vec::<u8>().expect("final readback");
    }
    (l.forgot, std::mem::take(&mut l.counts))
}

#[test]
fn random_safe_call_sequences_raise_no_validation_message() {
    let steps = std::env::var("VKSHADE_FUZZ_STEPS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(STEPS);
    let seed = std::env::var("VKSHADE_FUZZ_SEED")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(1);
    let ctx = [context(), context()];
    let make = |i: usize, name: &str| {
        ComputePipeline::from_spirv(&ctx[i], name, spirv(name).expect("built-in shader"))
            .expect("pipeline")
    };
    let world = World {
        scale: [make(0, "test/chain_scale"), make(1, "test/chain_scale")],
        pingpong: [make(0, "test/pingpong"), make(1, "test/pingpong")],
        buffers: Default::default(),
        images: Default::default(),
        ctx,
    };
    let forgot = std::thread::scope(|s| {
        let n_threads = std::env::var("VKSHADE_FUZZ_THREADS")
            .ok()
            .and_then(|s| s.parse().ok())
            .unwrap_or(2usize);
        let threads: Vec<_> = (0..n_threads)
            .map(|t| {
                let w = &world;
                s.spawn(move || run_thread(w, seed, t, steps))
            })
            .collect();
        let mut forgot = false;
        let mut counts = Counts::new();
        for t in threads {
            let (f, c) = t.join().expect("fuzz thread");
            forgot |= f;
            for (k, (ok, err)) in c {
                let e = counts.entry(k).or_default();
                e.0 += ok;
                e.1 += err;
            }
        }
        for (k, (ok, err)) in &counts {
            eprintln!("  {k:<36} {ok:>7} ok {err:>6} refused");
        }
        forgot
    });
    let World {
        ctx,
        scale,
        pingpong,
        buffers,
        images,
    } = world;
    drop((scale, pingpong, buffers, images));
    for c in ctx {
        c.wait_idle().expect("idle");
        let messages = c.messages().take();
        assert_clean(&messages);
        // A forgotten submission keeps its resources (and so the context) alive: that is
        // the documented leak, not an error.
        match c.shutdown() {
            Ok(m) => assert_clean(&m),
            Err(vkshade::Error::Leak(_)) if forgot => {}
            Err(e) => panic!("shutdown: {e}"),
        }
    }
    eprintln!("fuzz: seed {seed}, {steps} steps per thread, 2 contexts");
}
