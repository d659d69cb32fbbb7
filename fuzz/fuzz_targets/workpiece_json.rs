//! workpiece.json (`awl-workpiece/1`).
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let path = awl_fuzz::file("workpiece.json", data);
    if let Some(wp) = awl_fuzz::names_the_file(&path, awl::workpiece::json::read_workpiece(&path)) {
        if let Some(t) = wp.world_from_tag {
            assert!(t.to_homogeneous().iter().all(|v| v.is_finite()), "a finite T_world_tag");
        }
    }
});
