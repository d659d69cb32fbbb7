//! The process's allocator settings: glibc malloc with a single arena, large blocks mapped on their
//! own while a fuse streams its views, and the freed memory handed back to the system between the
//! fuse and the writing of its outputs.
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

/// Size from which [`map_view_sized_blocks`] has glibc map a block on its own: at every second
/// pixel of a 640 x 480 view, each of the view's per-point lists takes 0.5-1.5 MB.
const MAPPED_FROM_BYTES: i32 = 512 * 1024;

/// Has glibc map every block of 512 KiB or more on its own, returned to the system when freed,
/// instead of carving it out of the heap (`M_MMAP_THRESHOLD` fixed: glibc otherwise raises it to
/// the largest mapped block freed so far, up to 32 MiB, and after the first views' and the tag
/// search's buffers every view's lists come from the heap). Called when a fuse streams its views
/// (`view_memory = "stream"`): each view's lists, a little larger or smaller than the last
/// view's, then leave no heap holes that the model's lists, growing beside them, cannot reuse.
/// `awl fuse --preset fast`, 12-view box, 2 threads, 14 alternated runs: peak RSS 35.1 (33.3-39.1)
/// -> 32.1 (30.8-33.3) MiB, for 1.09x the wall time: 3x the page faults (BENCHMARKS.md 57). Not
/// for a fuse that holds every view (the default): there it cost 1.12x the time for 7 % less
/// memory.
pub fn map_view_sized_blocks() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    #[allow(unsafe_code)]
    // SAFETY: as in `one_arena`: `mallopt` only sets an allocator parameter; a refusal leaves
    // glibc's dynamic threshold, which is correct, only larger.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, MAPPED_FROM_BYTES);
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
