//! An `awl-arm/1` arm file (`awl pierce --robot-file`).
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let path = awl_fuzz::name("arm.json");
    let _ = awl_fuzz::names_the_file(&path, awl::kinematics::arm_file::parse_arm(&path, data));
});
