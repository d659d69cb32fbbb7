//! PLY: as a cloud (the readers `awl info`, `fuse`, `evaluate`, `register`, `pierce` use) and as a
//! mesh. A cloud read has only finite points; a mesh's triangles index its vertices.
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let path = awl_fuzz::name("cloud.ply");
    if let Some(cloud) = awl_fuzz::names_the_file(&path, awl::io::mesh::parse_cloud_checked(&path, data)) {
        let cloud = cloud.value;
        assert!(cloud.validate("cloud").is_ok(), "a cloud read holds only finite points");
    }
    if let Some(mesh) = awl_fuzz::names_the_file(&path, awl::io::mesh::parse_mesh_checked(&path, data)) {
        assert!(mesh.value.validate("mesh").is_ok(), "a mesh read is finite with its indices in range");
    }
});
