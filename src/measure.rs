//! The unit tests' global allocator: it counts the bytes live and their peak, so that
//! the tests of the memory estimators (`scene::footprint`, `format::footprint`,
//! `grade::footprint`, `output::footprint`) can check an estimate against what really
//! was allocated. `cargo nextest` runs each test in a process of its own, so no other
//! test counts into it. A leaf: it imports nothing of the crate.

use peak_alloc::PeakAlloc;

#[global_allocator]
static COUNTING: PeakAlloc = PeakAlloc;

/// Runs `f` and returns what it returns with the most bytes that were live at once
/// during it, beyond those live when it started.
pub(crate) fn peak<T>(f: impl FnOnce() -> T) -> (T, u64) {
    let base = COUNTING.current_usage();
    COUNTING.reset_peak_usage();
    let t = f();
    let peak = COUNTING.peak_usage().saturating_sub(base);
    (t, peak as u64)
}

/// Bytes live now.
pub(crate) fn live() -> u64 {
    COUNTING.current_usage() as u64
}
