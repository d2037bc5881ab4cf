//! The master's and the slave's 1 kHz steps allocate nothing: a counting global allocator
//! around many lockstep cycles of an impaired session (delay, jitter, loss, contact).
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::alloc::{GlobalAlloc, Layout, System};
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};

use h4_master::session::{self, Session};

struct Counting;

static COUNTING: AtomicBool = AtomicBool::new(false);
static ALLOCS: AtomicU64 = AtomicU64::new(0);

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        if COUNTING.load(Ordering::Relaxed) {
            ALLOCS.fetch_add(1, Ordering::Relaxed);
        }
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        if COUNTING.load(Ordering::Relaxed) {
            ALLOCS.fetch_add(1, Ordering::Relaxed);
        }
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

#[test]
fn master_and_slave_steps_allocate_nothing() {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../config/sessions/wall-push.toml");
    let o: Vec<String> = ["link.delay_ms=10", "link.jitter_ms=3", "link.loss=0.05"]
        .iter()
        .map(|s| s.to_string())
        .collect();
    let cfg = session::load(&path, &o).unwrap();
    let mut s = Session::new(&cfg).unwrap();
    // Warm up (first messages through the link's queues), then count through approach,
    // contact and hold.
    for _ in 0..200 {
        s.cycle().unwrap();
    }
    let mut max_force = 0.0f64;
    COUNTING.store(true, Ordering::SeqCst);
    for _ in 0..4000 {
        let (_m, sl) = s.cycle().unwrap();
        max_force = max_force.max(sl.out.wrench_measured[2].abs());
    }
    COUNTING.store(false, Ordering::SeqCst);
    let n = ALLOCS.load(Ordering::SeqCst);
    assert!(
        max_force > 2.0,
        "no contact in the counted cycles: {max_force} N"
    );
    assert_eq!(n, 0, "{n} allocations in 4000 cycles");
    // The counter works: an allocation is counted.
    COUNTING.store(true, Ordering::SeqCst);
    let v: Vec<u64> = Vec::with_capacity(std::hint::black_box(8));
    COUNTING.store(false, Ordering::SeqCst);
    drop(v);
    assert!(ALLOCS.load(Ordering::SeqCst) > 0);
}
