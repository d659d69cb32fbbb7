//! The whole `awl fuse` of the 12-view simulated box scan (seed 1, realistic noise: `awl simulate`'s
//! defaults), default configuration, all cores, outputs kept in memory (no `model.ply` or report
//! written). It takes tens of seconds per run, hence 3 samples.
//!
//! ```sh
//! nice -n 19 cargo bench -p awl --bench fuse
//! ```
//!
//! `bench/compare` times the CLI instead (1 and 2 threads, peak memory, accuracy against the CAD).

mod common;

use awl::pipeline::{FuseConfig, fuse};
use divan::Bencher;

fn main() {
    divan::main();
}

#[divan::bench(sample_count = 3, sample_size = 1)]
fn fuse_12_views(b: Bencher) {
    let scan = common::scan();
    let config = FuseConfig::default();
    b.bench(|| fuse(scan, &config, &|_, _, _| {}).expect("fuse"));
}
