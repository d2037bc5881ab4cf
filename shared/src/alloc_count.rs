//! A counting global allocator, to prove that a 1 kHz step allocates nothing. A test binary
//! installs it and counts what one closure allocates on the calling thread (the counter is per
//! thread, so the test harness's other threads do not interfere):
//!
//! ```ignore
//! #[global_allocator]
//! static GLOBAL: h4_shared::alloc_count::CountingAllocator = h4_shared::alloc_count::CountingAllocator;
//! assert_eq!(h4_shared::alloc_count::allocations_in(|| controller_step()), 0);
//! ```
#![allow(unsafe_code)] // a `GlobalAlloc` implementation: forwarding to `System` only.

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

/// The system allocator, counting every allocation (and reallocation) per thread.
pub struct CountingAllocator;

thread_local! {
    static ALLOCATIONS: Cell<u64> = const { Cell::new(0) };
}

fn count() {
    // `try_with`: allocations during thread teardown are not counted, never a panic.
    let _ = ALLOCATIONS.try_with(|n| n.set(n.get() + 1));
}

// SAFETY: every call is forwarded unchanged to the system allocator; the counter is a
// const-initialised thread-local without a destructor, which needs no allocation itself.
unsafe impl GlobalAlloc for CountingAllocator {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        count();
        // SAFETY: the caller upholds `GlobalAlloc::alloc`'s contract.
        unsafe { System.alloc(layout) }
    }
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        count();
        // SAFETY: as for `alloc`.
        unsafe { System.alloc_zeroed(layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        count();
        // SAFETY: the caller upholds `GlobalAlloc::realloc`'s contract.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: the caller upholds `GlobalAlloc::dealloc`'s contract.
        unsafe { System.dealloc(ptr, layout) }
    }
}

/// Allocations this thread made while running `f` (counted only where
/// [`CountingAllocator`] is the global allocator), and what `f` returned.
pub fn count_allocations<T>(f: impl FnOnce() -> T) -> (u64, T) {
    let before = ALLOCATIONS.with(Cell::get);
    let r = f();
    (ALLOCATIONS.with(Cell::get) - before, r)
}

/// Allocations this thread made while running `f`.
pub fn allocations_in(f: impl FnOnce()) -> u64 {
    count_allocations(f).0
}
