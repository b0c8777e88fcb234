//! The unit tests' global allocator: it counts the bytes live and their peak, so that
//! the tests of the memory estimators (`scene::footprint`, `format::footprint`,
//! `grade::footprint`, `output::footprint`) can check an estimate against what really
//! was allocated. No other test may count into it: `cargo nextest` runs each test in a
//! process of its own, and under `cargo test`, whose tests share a process and run side
//! by side, each measuring test runs itself again alone ([`alone`]). A leaf: it
//! imports nothing of the crate.

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

/// Set in a test process that runs one test alone.
const ALONE: &str = "RAYTILE_TEST_ALONE";

/// Whether the calling test, `test` (its path from the crate's root, as
/// `module_path!()` gives it), runs alone in its process and may measure. If not, it
/// is run again in a process of its own, where it measures and its assertions are
/// checked, and this returns `false` once that run passed: the caller then returns.
pub(crate) fn alone(test: &str) -> bool {
    if std::env::var_os(ALONE).is_some()
        || std::env::var_os("NEXTEST_EXECUTION_MODE").is_some_and(|m| m == "process-per-test")
    {
        return true;
    }
    let name = test.split_once("::").map_or(test, |(_, path)| path);
    let exe = std::env::current_exe().expect("the test binary's path");
    let run = std::process::Command::new(exe)
        .args([name, "--exact", "--test-threads=1", "--nocapture"])
        .env(ALONE, "1")
        .output()
        .expect("the test run again alone");
    let out = String::from_utf8_lossy(&run.stdout);
    assert!(
        run.status.success() && out.contains("1 passed"),
        "{name}, run alone, did not pass:\n{out}\n{}",
        String::from_utf8_lossy(&run.stderr)
    );
    false
}

/// Returns from the calling test unless it runs alone ([`alone`]), naming it by its
/// module and `name`.
macro_rules! alone_or_return {
    ($name:ident) => {
        if !$crate::measure::alone(concat!(module_path!(), "::", stringify!($name))) {
            return;
        }
    };
}
pub(crate) use alone_or_return;
