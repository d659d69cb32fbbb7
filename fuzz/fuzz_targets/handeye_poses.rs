//! The hand-eye poses file (`awl-handeye/1`).
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let path = awl_fuzz::name("poses.json");
    let _ = awl_fuzz::names_the_file(&path, awl::handeye::poses_file::parse_poses(&path, data));
});
