//! The process's allocator settings: glibc malloc with a single arena, and the freed memory handed
//! back to the system between the fuse and the writing of its outputs.
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

/// Hands the heap's free pages back to the system (glibc `malloc_trim`). glibc keeps freed memory
/// below the heap's top mapped for reuse; after the fuse that is most of its peak (~27 MB of the fast
/// preset's 30 MB heap on a 12-view box), while writing the outputs (the report's renders) takes
/// fresh pages: released first, the outputs do not add to the fuse's peak RSS.
pub fn release_free() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    #[allow(unsafe_code)]
    // SAFETY: `malloc_trim` only returns free pages of glibc's own heap to the system; it touches
    // no memory of ours and is thread-safe. Its result (whether anything was released) needs no
    // handling.
    unsafe {
        libc::malloc_trim(0);
    }
}
