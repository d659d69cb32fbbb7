//! Color JPEGs (baseline, progressive, gray), read by signature as `awl tags` and the fuse do.
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let path = awl_fuzz::file("color.jpg", data);
    if let Some(image) = awl_fuzz::names_the_file(&path, awl::io::image::read_color_image(&path)) {
        assert_eq!(image.data.len(), image.width as usize * image.height as usize);
    }
});
