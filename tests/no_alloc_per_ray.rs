//! The hot paths allocate nothing per ray once a thread is warm: a counting global allocator
//! wraps the system one, and after one warm-up ray per estimator, 200 more rays through
//! `data/cloud.vdb` (several samples each) must not allocate at all. Only the test's own thread
//! is counted, and only while it traces: the test harness's threads may allocate meanwhile
//! (a process-wide count failed once on a loaded machine).
//!
//! Excluded, and why: the power-series family (`unbiased-raymarch`, `jackknife`: per-sample
//! coefficient vectors whose length is the random series order).
#![allow(unsafe_code, clippy::unwrap_used, clippy::expect_used, missing_docs)]

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::sync::atomic::{AtomicU64, Ordering};
use umbra::estimate::{estimate, Estimator, Options};
use umbra::{Interp, Ray, Volume};

struct Counting;

static ALLOCS: AtomicU64 = AtomicU64::new(0);

thread_local! {
    /// Whether this thread's allocations are counted (const-initialised: reading it never
    /// allocates).
    static COUNTING: Cell<bool> = const { Cell::new(false) };
}

/// Count an allocation of the current thread if it is being counted.
fn count() {
    if COUNTING.try_with(Cell::get).unwrap_or(false) {
        ALLOCS.fetch_add(1, Ordering::Relaxed);
    }
}

// SAFETY: forwards every call to the system allocator unchanged; only counts.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        count();
        System.alloc(layout)
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        System.dealloc(ptr, layout);
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        count();
        System.realloc(ptr, layout, new_size)
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

#[test]
fn estimators_do_not_allocate_per_ray() {
    let vol = Volume::load("data/cloud.vdb", "density", 4.0).unwrap();
    let [lo, hi] = vol.value_box().unwrap();
    let (lo, hi) = (
        vol.to_world(lo.map(|c| c as f64)),
        vol.to_world(hi.map(|c| c as f64 + 1.0)),
    );
    // Deterministic chords of the value box: a fixed lattice of start and end points.
    let rays: Vec<Ray> = (0..200)
        .map(|i| {
            let f = |k: usize, a: usize| ((i * (7 + 3 * a) + k * 13) % 97) as f64 / 96.0;
            let p = |k: usize| [0, 1, 2].map(|a| lo[a] + (hi[a] - lo[a]) * f(k, a));
            let (a, b) = (p(0), p(1));
            let d = [0, 1, 2].map(|k| b[k] - a[k]);
            Ray::between(
                [0, 1, 2].map(|k| a[k] - 2.0 * d[k]),
                [0, 1, 2].map(|k| a[k] + 3.0 * d[k] + 1e-3),
            )
            .unwrap()
        })
        .collect();
    // Every estimator but the power-series family (see the module comment).
    let names =
        umbra::estimate::names().filter(|n| !matches!(*n, "unbiased-raymarch" | "jackknife"));
    for name in names {
        let est = Estimator::from_name(name).unwrap();
        for interp in [Interp::Trilinear, Interp::Nearest] {
            let opts = Options {
                interp,
                samples: 4,
                ..Options::default()
            };
            // Warm up this thread's buffers (they grow to the longest ray once).
            for r in &rays {
                estimate(&vol, r, 0, &est, &opts).unwrap();
            }
            let before = ALLOCS.load(Ordering::Relaxed);
            let mut sum = 0.0;
            COUNTING.with(|c| c.set(true));
            for (i, r) in rays.iter().enumerate() {
                sum += estimate(&vol, r, i as u64, &est, &opts).unwrap().value;
            }
            COUNTING.with(|c| c.set(false));
            let allocs = ALLOCS.load(Ordering::Relaxed) - before;
            assert!(sum.is_finite() && sum > 0.0, "{name}: {sum}");
            assert_eq!(
                allocs, 0,
                "{name} ({interp:?}) allocated {allocs} times in 200 rays"
            );
        }
    }
}
