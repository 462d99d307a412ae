//! A second thread for the large products inside one step.
//!
//! A reduced step at r = 250 streams a few MB of basis rows through four
//! products (the vertex displacements `W q`, their pull-back `W^T f`, the
//! inertia's mode products and the online estimate's sample positions); each
//! takes 20-100 us. Starting a pool thread for
//! them (rayon's join) costs more than it saves (docs/results.md section 65),
//! so [`join`] hands its second half to one persistent thread that spins
//! between the products of a step and sleeps after [`SPIN`] without work.
//!
//! Callers split a product by its outputs (rows of `W q`, entries of `W^T f`),
//! so each output is summed in the same order whichever thread computes it: a
//! step is the same, bit for bit, with or without the second thread. When the
//! helper is busy (another simulation's step on another thread), has not
//! picked the work up by the time the caller's own half is done, was late by
//! more than [`LATE`] within the last [`BACK_OFF_JOINS`] joins (other work
//! holds the cores), is switched
//! off ([`set_enabled`], or [`alone`] on this thread: the workers of
//! [`crate::batch::step_many`], which have the cores already), or the machine
//! has one core, the caller runs both halves itself.

use faer::linalg::matmul::matmul;
use faer::{Accum, MatMut, MatRef, Par};
use std::cell::{Cell, UnsafeCell};
use std::hint::spin_loop;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::sync::atomic::{AtomicBool, AtomicU32, AtomicU8, Ordering};
use std::sync::{Arc, OnceLock};
use std::thread::{self, Thread};
use std::time::{Duration, Instant};

/// How long the helper waits for its next job, yielding its core to any other
/// thread that wants it, before it sleeps: longer than the gaps between a
/// step's products, short enough not to hold a core between steps driven from
/// Python.
pub const SPIN: Duration = Duration::from_micros(300);

const IDLE: u8 = 0;
const POSTED: u8 = 1;
const RUNNING: u8 = 2;
const DONE: u8 = 3;

type Job = *mut (dyn FnMut() + Send);

struct Shared {
    state: AtomicU8,
    /// Held by the caller that posted the current job.
    taken: AtomicBool,
    sleeping: AtomicBool,
    panicked: AtomicBool,
    job: UnsafeCell<Option<Job>>,
}

// SAFETY: `job` is written by the caller holding `taken` before it publishes
// POSTED (Release) and read by the helper after it wins POSTED -> RUNNING
// (Acquire); the caller does not return before the job is DONE or taken back.
unsafe impl Sync for Shared {}
unsafe impl Send for Shared {}

struct Helper {
    shared: Arc<Shared>,
    thread: Thread,
}

static ENABLED: AtomicBool = AtomicBool::new(true);

/// A helper that finishes its half this much later than the caller has been
/// taken off its core (the machine's cores are busy with other work).
pub const LATE: Duration = Duration::from_micros(50);

/// Joins run on the calling thread alone after a late helper: a few steps'
/// products at r = 250; then the helper is tried again.
pub const BACK_OFF_JOINS: u32 = 512;

static BACK_OFF: AtomicU32 = AtomicU32::new(0);

thread_local! {
    static ALONE: Cell<bool> = const { Cell::new(false) };
}

/// Runs `f` with every [`join`] on this thread done here, both halves.
pub fn alone<R>(f: impl FnOnce() -> R) -> R {
    /// Restores the thread's setting on every way out, unwinding included.
    struct Restore(bool);
    impl Drop for Restore {
        fn drop(&mut self) {
            ALONE.with(|a| a.set(self.0));
        }
    }
    let _restore = Restore(ALONE.with(|a| a.replace(true)));
    f()
}

/// Whether [`join`] may use the second thread (default: yes where the machine
/// has two cores or more). Results do not depend on it.
pub fn set_enabled(on: bool) {
    ENABLED.store(on, Ordering::Relaxed);
}

fn helper() -> Option<&'static Helper> {
    static HELPER: OnceLock<Option<Helper>> = OnceLock::new();
    HELPER
        .get_or_init(|| {
            if thread::available_parallelism().map_or(1, |n| n.get()) < 2 {
                return None;
            }
            let shared = Arc::new(Shared {
                state: AtomicU8::new(IDLE),
                taken: AtomicBool::new(false),
                sleeping: AtomicBool::new(false),
                panicked: AtomicBool::new(false),
                job: UnsafeCell::new(None),
            });
            let inner = Arc::clone(&shared);
            let handle = thread::Builder::new().name("licrom-second".into()).spawn(move || serve(&inner)).ok()?;
            Some(Helper { shared, thread: handle.thread().clone() })
        })
        .as_ref()
}

fn serve(s: &Shared) {
    loop {
        let idle_since = Instant::now();
        let mut spins = 0u32;
        while s.state.load(Ordering::Acquire) != POSTED {
            spins = spins.wrapping_add(1);
            if spins.is_multiple_of(256) && idle_since.elapsed() > SPIN {
                s.sleeping.store(true, Ordering::SeqCst);
                if s.state.load(Ordering::SeqCst) != POSTED {
                    thread::park();
                }
                s.sleeping.store(false, Ordering::SeqCst);
            }
            // Spinning, but handing the core to any other thread that waits for it: on busy cores the
            // caller's own half, or other processes, come first.
            thread::yield_now();
        }
        if s.state.compare_exchange(POSTED, RUNNING, Ordering::Acquire, Ordering::Relaxed).is_ok() {
            // SAFETY: see `Shared`: the poster waits for DONE before the job's borrows end.
            let job = unsafe { (*s.job.get()).expect("a posted job") };
            if catch_unwind(AssertUnwindSafe(|| unsafe { (*job)() })).is_err() {
                s.panicked.store(true, Ordering::Relaxed);
            }
            s.state.store(DONE, Ordering::Release);
        }
    }
}

/// Runs `a` and `b`, `b` on the second thread where it is free and picks it
/// up in time, else both here.
pub fn join<A: FnOnce(), B: FnOnce() + Send>(a: A, b: B) {
    let Some(h) = helper().filter(|_| ENABLED.load(Ordering::Relaxed) && !ALONE.with(Cell::get)) else {
        a();
        b();
        return;
    };
    let s = &*h.shared;
    let backing_off = BACK_OFF.fetch_update(Ordering::Relaxed, Ordering::Relaxed, |j| j.checked_sub(1)).is_ok();
    if backing_off || s.taken.compare_exchange(false, true, Ordering::Acquire, Ordering::Relaxed).is_err() {
        a();
        b();
        return;
    }
    let mut b = Some(b);
    let mut call = || {
        if let Some(b) = b.take() {
            b()
        }
    };
    let job: *mut (dyn FnMut() + Send + '_) = &mut call;
    // SAFETY: the lifetime is erased for the helper's slot only; `Posted`'s
    // drop, on every way out of this function, waits until the helper is done.
    let job: Job = unsafe { std::mem::transmute(job) };
    unsafe { *s.job.get() = Some(job) };
    let posted = Posted(s);
    s.state.store(POSTED, Ordering::SeqCst);
    if s.sleeping.load(Ordering::SeqCst) {
        h.thread.unpark();
    }
    a();
    if posted.take_back() {
        call();
    }
}

/// A job handed to the helper. Dropped on every way out of [`join`], unwinding
/// included: takes the job back where the helper has not started it, else
/// waits until the helper is done, so no borrow of the job outlives it; then
/// frees the helper, and re-raises a panic of its half.
struct Posted<'a>(&'a Shared);

impl Posted<'_> {
    /// Whether the job was taken back before the helper started it (the
    /// caller then runs it).
    fn take_back(&self) -> bool {
        self.0.state.compare_exchange(POSTED, IDLE, Ordering::Acquire, Ordering::Relaxed).is_ok()
    }
}

impl Drop for Posted<'_> {
    fn drop(&mut self) {
        let s = self.0;
        if !self.take_back() {
            let since = Instant::now();
            let mut spins = 0u32;
            while !matches!(s.state.load(Ordering::Acquire), DONE | IDLE) {
                spins = spins.wrapping_add(1);
                if spins.is_multiple_of(256) && since.elapsed() > LATE {
                    // The helper was taken off its core mid-job: the cores are busy. Give it ours, and
                    // do the next products alone.
                    BACK_OFF.store(BACK_OFF_JOINS, Ordering::Relaxed);
                }
                if spins > 64 {
                    thread::yield_now();
                } else {
                    spin_loop();
                }
            }
        }
        s.state.store(IDLE, Ordering::Relaxed);
        unsafe { *s.job.get() = None };
        let panicked = s.panicked.swap(false, Ordering::Relaxed);
        s.taken.store(false, Ordering::Release);
        if panicked && !thread::panicking() {
            panic!("the second thread's half of a product panicked");
        }
    }
}

/// Products of fewer multiply-adds than this run whole on the calling thread:
/// handing half of one over costs about a microsecond.
const SPLIT_ABOVE: usize = 32 * 1024;

/// `out = a b` (or `out += a b` with [`Accum::Add`]), the rows of `a` and
/// `out` in two halves over [`join`]. Each row of `out` is one product of a
/// row of `a` with `b`, so the split depends on the sizes alone and the result
/// on nothing else.
pub(crate) fn product_by_rows(a: MatRef<'_, f64>, b: MatRef<'_, f64>, out: MatMut<'_, f64>, accum: Accum) {
    let rows = a.nrows();
    if rows < 16 || rows * a.ncols() * b.ncols() < SPLIT_ABOVE {
        matmul(out, accum, a, b, 1.0, Par::Seq);
        return;
    }
    let half = (rows / 2).next_multiple_of(8);
    let (top, bottom) = out.split_at_row_mut(half);
    let (a_top, a_bottom) = a.split_at_row(half);
    join(|| matmul(top, accum, a_top, b, 1.0, Par::Seq), || matmul(bottom, accum, a_bottom, b, 1.0, Par::Seq));
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `f` on this thread alone (`alone`) or with the helper where it is free.
    fn with_helper<R>(on: bool, f: impl FnOnce() -> R) -> R {
        if on {
            f()
        } else {
            alone(f)
        }
    }

    #[test]
    fn both_halves_run_once_with_or_without_the_helper() {
        for on in [true, false] {
            for n in 0..200 {
                let (mut x, mut y) = (vec![0u64; n], vec![0u64; n]);
                with_helper(on, || {
                    join(
                        || x.iter_mut().enumerate().for_each(|(i, v)| *v += i as u64),
                        || y.iter_mut().enumerate().for_each(|(i, v)| *v += 2 * i as u64),
                    )
                });
                assert!(x.iter().enumerate().all(|(i, &v)| v == i as u64));
                assert!(y.iter().enumerate().all(|(i, &v)| v == 2 * i as u64));
            }
        }
    }

    #[test]
    fn a_split_product_is_the_same_on_one_thread_or_two_and_the_product() {
        let (rows, n, cols) = (1801, 257, 2);
        let a: Vec<f64> = (0..rows * n).map(|i| ((i * 7919) % 1013) as f64 / 1013.0 - 0.5).collect();
        let b: Vec<f64> = (0..n * cols).map(|i| ((i * 104729) % 997) as f64 / 997.0 - 0.5).collect();
        let run = |on: bool, a: MatRef<'_, f64>, b: &[f64]| {
            let mut out = vec![0.0; a.nrows() * cols];
            with_helper(on, || {
                product_by_rows(
                    a,
                    MatRef::from_column_major_slice(b, a.ncols(), cols),
                    MatMut::from_column_major_slice_mut(&mut out, a.nrows(), cols),
                    Accum::Replace,
                )
            });
            out
        };
        let am = MatRef::from_row_major_slice(&a, rows, n);
        let one = run(false, am, &b);
        // Repeated: the helper takes the second half in most of them (where it is late, the caller does).
        for _ in 0..20 {
            assert_eq!(run(true, am, &b), one);
        }
        for r in 0..rows {
            for c in 0..cols {
                let exact: f64 = (0..n).map(|k| a[r * n + k] * b[c * n + k]).sum();
                assert!((one[c * rows + r] - exact).abs() < 1e-12 * n as f64);
            }
        }
        // The transposed layout (the pull-back `W^T f`) splits the same way.
        let at = MatRef::from_row_major_slice(&a, rows, n).transpose();
        let f: Vec<f64> = (0..rows * cols).map(|i| ((i * 31) % 101) as f64 / 101.0).collect();
        let one = run(false, at, &f);
        for _ in 0..20 {
            assert_eq!(run(true, at, &f), one);
        }
    }

    #[test]
    fn alone_is_undone_on_every_way_out() {
        assert!(std::panic::catch_unwind(|| alone(|| panic!("inside"))).is_err());
        assert!(!ALONE.with(Cell::get));
        alone(|| alone(|| ()));
        assert!(!ALONE.with(Cell::get));
    }

    #[test]
    fn a_panic_in_either_half_reaches_the_caller_and_frees_the_helper() {
        for second in [false, true] {
            let caught = std::panic::catch_unwind(|| {
                let mut x = vec![0u64; 1000];
                join(
                    || assert!(second, "first half"),
                    || {
                        x.iter_mut().for_each(|v| *v += 1);
                        assert!(!second, "second half");
                    },
                );
            });
            assert!(caught.is_err());
        }
        let (mut x, mut y) = (0, 0);
        join(|| x = 1, || y = 2);
        assert_eq!((x, y), (1, 2));
    }

    #[test]
    fn callers_on_many_threads_each_get_their_halves() {
        thread::scope(|sc| {
            for t in 0..4u64 {
                sc.spawn(move || {
                    for _ in 0..500 {
                        let (mut x, mut y) = (0u64, 0u64);
                        join(|| x = t, || y = t + 10);
                        assert_eq!((x, y), (t, t + 10));
                    }
                });
            }
        });
    }
}
