//! A scan's views held in memory ([`awl::scan::ViewData::Images`]) load as the same files do: the
//! same points, pixels and colors at every pixel step, the same color image for the tag search; a
//! scan whose views are in memory cannot be written as a manifest naming no files.
#![cfg(feature = "sim")]

use awl::io::scan::{load_depth_points, load_view_every_nth, read_scan, read_view_color, write_scan};
use awl::sim::{SceneKind, SimParams, simulate, write_simulation};

#[test]
fn in_memory_views_load_as_their_files_do() {
    let sim = simulate(&SimParams { views: 2, seed: 3, ..SimParams::scan(SceneKind::Shell) }).expect("simulate");
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("scan");
    write_simulation(&path, &sim, false).expect("write");
    let files = read_scan(&path).expect("read");
    let memory = sim.in_memory_scan();
    for index in 0..2 {
        for step in [1, 2, 3] {
            let (f, m) = (
                load_view_every_nth(&files, index, None, step).expect("file view"),
                load_view_every_nth(&memory, index, None, step).expect("memory view"),
            );
            assert!(f.cloud_camera.len() > 10_000 / step, "view {index} step {step}: {} points", f.cloud_camera.len());
            assert!(f.cloud_camera == m.cloud_camera, "view {index} step {step}: points differ");
            assert!(f.pixels == m.pixels, "view {index} step {step}: pixels differ");
            assert!(f.color == m.color, "view {index} step {step}: colors differ");
            let moved = (f.world_from_camera.inverse() * m.world_from_camera).translation.vector.norm();
            assert!(moved < 1e-12, "view {index}: the recorded pose differs by {moved} m");
        }
        let color = read_view_color(&memory, index).expect("color").expect("a color image");
        assert_eq!(Some(color), read_view_color(&files, index).expect("color"));
        assert_eq!(
            load_depth_points(&memory, index, None).expect("depth"),
            load_depth_points(&files, index, None).expect("depth")
        );
    }
}

#[test]
fn a_scan_in_memory_is_not_written_as_a_manifest() {
    let sim = simulate(&SimParams { views: 2, seed: 3, ..SimParams::scan(SceneKind::Box) }).expect("simulate");
    let dir = tempfile::tempdir().expect("tempdir");
    let mut scan = sim.in_memory_scan();
    scan.dir = dir.path().to_path_buf();
    let err = write_scan(&scan).expect_err("no files to name").to_string();
    assert!(err.contains("views[0]") && err.contains("memory"), "{err}");
    assert!(!dir.path().join("scan.json").exists(), "nothing written");
}

/// A view loaded at every `step`-th pixel, from images decoded on that grid only: the points,
/// colors and pixel numbers of the full images back-projected at that step.
#[test]
fn every_nth_pixel_equals_the_full_images_at_that_step() {
    use awl::camera::{depth_to_cloud_every_nth, every_nth_grid};
    use awl::io::image::{read_color_image, read_depth_png};
    use awl::scan::ViewData;
    let sim = simulate(&SimParams { views: 1, seed: 5, ..SimParams::scan(SceneKind::Box) }).expect("simulate");
    let dir = tempfile::tempdir().expect("tempdir");
    write_simulation(dir.path(), &sim, false).expect("write");
    let scan = read_scan(dir.path()).expect("read");
    let ViewData::Depth { depth, color: Some(color) } = &scan.views[0].data else { panic!("a color depth view") };
    let camera = scan.depth_camera().expect("camera");
    let full_depth = read_depth_png(&scan.dir.join(depth)).expect("depth");
    let full_color = read_color_image(&scan.dir.join(color)).expect("color");
    for step in [1, 2, 3] {
        let rays = camera.intrinsics.ray_table_every_nth(step);
        let (want, want_pixels) = depth_to_cloud_every_nth(&full_depth, Some(&full_color), camera, &rays, step);
        assert!(want.len() > 10_000 / (step * step), "{} points at step {step}", want.len());
        for table in [Some(rays.as_slice()), None] {
            let got = load_view_every_nth(&scan, 0, table, step).expect("view");
            assert_eq!(got.cloud_camera, want, "step {step}");
            assert_eq!(got.pixels.as_deref(), Some(want_pixels.as_slice()), "step {step}");
            let thinned = got.color.expect("color image");
            let (w, h) = every_nth_grid(full_color.width as usize, full_color.height as usize, step);
            assert_eq!((thinned.width as usize, thinned.height as usize), (w, h));
            assert_eq!(thinned.data[w + 1], full_color.data[step * full_color.width as usize + step]);
        }
    }
}
