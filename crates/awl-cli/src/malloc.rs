//! The process's one allocator setting: glibc malloc with a single arena.
//!
//! By default glibc gives each thread that allocates its own arena (up to 8 per core), and memory
//! freed in one arena is only reused by allocations in that arena. The fuse's views, levels and
//! merge are allocated by whichever rayon worker runs them, so at 2 threads each arena kept the
//! holes of the other's peak: `awl fuse --preset fast` on a simulated 12-view box had a peak RSS of
//! 46-56 MB at 2 threads against 35 MB at 1. One arena: 38-41 MB, in the same wall time (5 runs
//! each, BENCHMARKS.md 54). Other platforms and allocators: nothing to set.

/// Makes every thread allocate from glibc's main arena (see the module docs). Called first thing in
/// `main`, before any thread starts.
pub fn one_arena() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    #[allow(unsafe_code)]
    // SAFETY: `mallopt` only sets an allocator parameter, which glibc allows at any time from any
    // thread; it reads and writes no memory of ours. A refusal (return value 0) leaves glibc's
    // default in place, which is correct, only larger: nothing to handle.
    unsafe {
        libc::mallopt(libc::M_ARENA_MAX, 1);
    }
}
