//! Renders of known clouds: coverage against the projected area, Lambert colors by hand, scalar
//! colors and legend, and bit-identical pictures for 1 and 2 threads.

use nalgebra::{Point3, Vector3};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::*;
use crate::cloud::PointCloud;

/// An `n` x `n` grid on the 1 m square x, z in [0, 1) at y = 0 (facing -y, toward the front view).
fn wall(n: usize, color: [u8; 3]) -> PointCloud {
    let step = 1.0 / n as f32;
    let points: Vec<Point3<f32>> =
        (0..n * n).map(|k| Point3::new((k % n) as f32 * step, 0.0, (k / n) as f32 * step)).collect();
    let len = points.len();
    PointCloud { points, normals: Some(vec![Vector3::new(0.0, -1.0, 0.0); len]), colors: Some(vec![color; len]) }
}

fn covered(img: &crate::image::ColorImage, bg: [u8; 3]) -> usize {
    img.data.iter().filter(|p| **p != bg).count()
}

fn params(w: u32, h: u32) -> RenderParams {
    RenderParams { width: w, height: h, margin_px: 10, ..RenderParams::default() }
}

#[test]
fn wall_from_the_front_fills_its_square_with_the_lambert_color() {
    let cloud = wall(200, [255, 0, 0]);
    let img = render_cloud(&cloud, Viewpoint::Front, &params(400, 300)).expect("render");
    // Extent 0.995 m onto 280 px (281.4 px/m); discs of 1.5 x 5 mm = 2.11 px widen each side.
    let n = covered(&img, [255; 3]) as f64;
    let side = 280.0 + 2.0 * 2.11;
    assert!((n / (side * side) - 1.0).abs() < 0.02, "covered {n}");
    // Normal toward the viewer: k = 0.25 + 0.75 * |l_z| = 0.25 + 0.75 / |(-0.4, 0.5, -1)| = 0.8816.
    assert_eq!(img.data[150 * 400 + 200], [225, 0, 0]);
    // Edge-on (top: 381.9 px/m, side: 281.4 px/m) the wall is a line one disc thick: at most
    // 2 x 1.5 x 5 mm x 381.9 px/m = 5.7 px across, and 280 px or more long.
    for view in [Viewpoint::Top, Viewpoint::Side] {
        let img = render_cloud(&cloud, view, &params(400, 300)).expect("render");
        let on: Vec<(usize, usize)> =
            (0..300 * 400).filter(|&k| img.data[k] != [255; 3]).map(|k| (k % 400, k / 400)).collect();
        let span = |f: fn(&(usize, usize)) -> usize| {
            on.iter().map(f).max().unwrap_or(0) - on.iter().map(f).min().unwrap_or(0) + 1
        };
        let (w, h) = (span(|p| p.0), span(|p| p.1));
        assert!(w.min(h) <= 6 && w.max(h) >= 280, "{view:?}: the wall is edge-on, {w} x {h} px");
    }
}

#[test]
fn sphere_without_normals_is_a_disc_shaded_by_depth() {
    // 20 000 points on a Fibonacci sphere of radius 0.5 m: from the top a disc of radius 140 px.
    let n = 20_000;
    let golden = std::f32::consts::PI * (3.0 - 5f32.sqrt());
    let points = (0..n)
        .map(|k| {
            let z = 1.0 - 2.0 * (k as f32 + 0.5) / n as f32;
            let r = (1.0 - z * z).sqrt();
            let a = golden * k as f32;
            Point3::new(0.5 * r * a.cos(), 0.5 * r * a.sin(), 0.5 * z)
        })
        .collect();
    let cloud = PointCloud::from_points(points);
    // Spacing 12.5 mm (sphere area / points = 0.157 mm2, its root 12.5 mm) at 280 px/m: discs of
    // 1.5 x 3.5 = 5.25 px widen the disc by that radius.
    let p = RenderParams { spacing_m: Some(0.0125), ..params(300, 300) };
    let img = render_cloud(&cloud, Viewpoint::Top, &p).expect("render");
    let area = std::f64::consts::PI * 145.25 * 145.25;
    let n = covered(&img, [255; 3]) as f64;
    assert!((n / area - 1.0).abs() < 0.02, "covered {n} vs {area:.0}");
    let centre = img.data[150 * 300 + 150][0];
    let rim = img.data[150 * 300 + 150 + 135][0];
    // Depth cue k = 1 - 0.55 (d - dmin) / (dmax - dmin): the top (d = -0.5) keeps 190; 135 px out the
    // surface is at z = sqrt(0.25 - (0.5 * 135 / 140)^2) = 0.133, so k = 1 - 0.55 * 0.367 = 0.798: 152.
    assert_eq!(centre, 190);
    assert!((i32::from(rim) - 152).abs() <= 5, "rim {rim}");
}

#[test]
fn scalar_render_maps_values_and_draws_the_legend() {
    let cloud = wall(200, [0; 3]);
    let values: Vec<f32> = cloud.points.iter().map(|p| p.x * 4e-3).collect(); // 0..4 mm along x
    let scale = ScalarScale { colormap: Colormap::Turbo, lo_m: 0.0, hi_m: 4e-3 };
    let p = params(500, 400);
    let (img, legend) = render_scalar(&cloud, &values, &scale, Viewpoint::Front, &p).expect("render");
    let px = |x: u32, y: u32| img.data[(y * 500 + x) as usize];
    // Scene: 500 - legend width; the wall's left column has x = 0 (t = 0) and is at the margin + shift.
    let row = 200;
    let first = (0..legend.bar_x).find(|&x| px(x, row) != [255; 3]).expect("wall drawn");
    let last = (0..legend.bar_x).rev().find(|&x| px(x, row) != [255; 3]).expect("wall drawn");
    assert_eq!(px(first, row), Colormap::Turbo.rgb(0.0));
    let t_last = 0.995 * 4e-3 / 4e-3;
    let expect = Colormap::Turbo.rgb(t_last);
    assert!(px(last, row).iter().zip(expect).all(|(a, b)| a.abs_diff(b) <= 6), "{:?} {expect:?}", px(last, row));
    // The legend bar carries the colormap: top = high end, bottom = low end.
    assert_eq!(px(legend.bar_x + 1, legend.bar_top), Colormap::Turbo.rgb(1.0));
    assert_eq!(px(legend.bar_x + 1, legend.bar_bottom), Colormap::Turbo.rgb(0.0));
    assert!(legend.bar_bottom - legend.bar_top > 300, "{legend:?}");
    assert!(render_scalar(&cloud, &values[1..], &scale, Viewpoint::Front, &p).is_err(), "value count checked");
}

#[test]
fn bad_input_is_an_error() {
    let p = RenderParams::default();
    assert!(render_cloud(&PointCloud::default(), Viewpoint::Iso, &p).is_err());
    let nan = PointCloud::from_points(vec![Point3::new(f32::NAN, 0.0, 0.0)]);
    assert!(render_cloud(&nan, Viewpoint::Iso, &p).is_err());
    let tiny = RenderParams { width: 8, ..RenderParams::default() };
    assert!(render_cloud(&wall(4, [0; 3]), Viewpoint::Iso, &tiny).is_err());
}

#[test]
fn spacing_of_a_grid() {
    let s = estimate_spacing(&wall(200, [0; 3]).points).expect("finite");
    assert!((s - 0.005).abs() < 1e-5, "{s}");
    let s = estimate_spacing(&wall(400, [0; 3]).points).expect("finite");
    assert!((s - 0.0025).abs() < 1e-5, "{s}");
    assert_eq!(estimate_spacing(&[Point3::origin()]).expect("finite"), 0.0);
}

#[test]
fn one_and_two_threads_give_the_same_pixels_and_png_round_trips() {
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let n = 60_000;
    let points: Vec<Point3<f32>> = (0..n).map(|_| Point3::new(rng.random(), rng.random(), rng.random())).collect();
    let normals = (0..n).map(|_| Vector3::new(rng.random::<f32>() - 0.5, 0.3, 0.5).normalize()).collect();
    let colors = (0..n).map(|_| [rng.random(), rng.random(), rng.random()]).collect();
    let cloud = PointCloud { points, normals: Some(normals), colors: Some(colors) };
    let values: Vec<f32> = (0..n).map(|k| k as f32 * 1e-7).collect();
    let scale = ScalarScale { colormap: Colormap::Viridis, lo_m: 0.0, hi_m: 6e-3 };
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("pool");
        pool.install(|| {
            let p = RenderParams::default();
            let a = render_cloud(&cloud, Viewpoint::Iso, &p).expect("render");
            let (b, _) = render_scalar(&cloud, &values, &scale, Viewpoint::Top, &p).expect("render");
            (a, b)
        })
    };
    let one = run(1);
    let two = run(2);
    assert!(one == two, "1 vs 2 threads differ");
    assert!(covered(&one.0, [255; 3]) > 100_000, "the cube covers the picture");
    let png = png_bytes(&one.0).expect("encode");
    let mut reader = png::Decoder::new(std::io::Cursor::new(png)).read_info().expect("decode");
    let mut buf = vec![0; reader.output_buffer_size().expect("size")];
    reader.next_frame(&mut buf).expect("frame");
    let decoded: Vec<u8> = one.0.data.iter().flatten().copied().collect();
    assert_eq!(buf, decoded);
}
