//! OBJ meshes: finite vertices, triangles that index them.
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let path = awl_fuzz::name("mesh.obj");
    if let Some(mesh) = awl_fuzz::names_the_file(&path, awl::io::mesh::parse_mesh_checked(&path, data)) {
        assert!(mesh.value.validate("mesh").is_ok(), "a mesh read is finite with its indices in range");
    }
});
