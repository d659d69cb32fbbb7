//! PCD (ascii, binary, binary_compressed): as a cloud, and organised (NaNs kept, the grid size).
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let path = awl_fuzz::name("cloud.pcd");
    if let Some(cloud) = awl_fuzz::names_the_file(&path, awl::io::mesh::parse_cloud_checked(&path, data)) {
        assert!(cloud.value.validate("cloud").is_ok(), "a cloud read holds only finite points");
    }
    if let Some(grid) = awl_fuzz::names_the_file(&path, awl::io::pcd::parse_pcd_organised(&path, data)) {
        assert_eq!(grid.cloud.len(), grid.width * grid.height, "an organised cloud fills its grid");
    }
});
