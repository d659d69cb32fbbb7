//! scan.json (`awl-scan/1`): the manifest read and validated (its files are not there).
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let path = awl_fuzz::file("scan.json", data);
    if let Some(scan) = awl_fuzz::names_the_file(&path, awl::io::scan::read_scan(&path)) {
        for i in 0..scan.views.len() {
            let pose = scan.world_from_camera(i);
            assert!(pose.is_ok_and(|p| p.to_homogeneous().iter().all(|v| v.is_finite())), "view {i}: a finite pose");
        }
    }
});
