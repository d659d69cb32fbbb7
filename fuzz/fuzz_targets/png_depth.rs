//! 16-bit depth PNGs, whole and on every 3rd pixel (as a fuse with `pixel_step = 3` reads them).
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let path = awl_fuzz::file("depth.png", data);
    if let Some(image) = awl_fuzz::names_the_file(&path, awl::io::image::read_depth_png(&path)) {
        assert_eq!(image.data.len(), image.width as usize * image.height as usize);
    }
    let thinned = awl::io::image::read_depth_png_every_nth(&path, 3);
    if let Some((image, (w, h))) = awl_fuzz::names_the_file(&path, thinned) {
        assert_eq!((image.width, image.height), (w.div_ceil(3), h.div_ceil(3)));
    }
});
