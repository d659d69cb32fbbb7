//! Helpers shared by the integration tests.
#![allow(dead_code)]

use std::path::PathBuf;

use awl::image::ColorImage;

/// The shared test data folder: `$AWL_SHARED_DATA` when set, else `<workspace>/../shared/data`.
/// Panics (fails the test) when it is missing: CI has it beside the checkout.
pub fn shared_data() -> PathBuf {
    let dir = std::env::var_os("AWL_SHARED_DATA")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data"));
    assert!(
        dir.is_dir(),
        "shared test data folder {} is missing: restore it (see shared/data/SOURCES.md) or set AWL_SHARED_DATA",
        dir.display()
    );
    dir
}

/// `truth` (a hand-eye `T_ee_camera`) moved by `deg` about one fixed axis and `mm` along one fixed
/// direction, neither along a camera axis: the wrong recorded hand-eye of the hand-eye tests.
pub fn hand_eye_off(truth: &nalgebra::Isometry3<f64>, deg: f64, mm: f64) -> nalgebra::Isometry3<f64> {
    use nalgebra::{Isometry3, Translation3, Unit, UnitQuaternion, Vector3};
    let off = Isometry3::from_parts(
        Translation3::from(Vector3::new(-0.3, 0.8, 0.52).normalize() * (mm / 1000.0)),
        UnitQuaternion::from_axis_angle(&Unit::new_normalize(Vector3::new(0.6, -0.5, 0.62)), deg.to_radians()),
    );
    truth * off
}

/// `image` with every channel scaled by `gain` (a dim scene).
pub fn dimmed(image: &ColorImage, gain: f32) -> ColorImage {
    let data = image.data.iter().map(|p| p.map(|c| (f32::from(c) * gain).round() as u8)).collect();
    ColorImage { data, ..*image }
}

/// A fused model against its truth (the `eval` feature).
#[cfg(feature = "eval")]
mod against_truth {
    use awl::PointCloud;
    use awl::camera::DepthCamera;
    use awl::eval::{MeshDistance, cad_metrics, trajectory_error_mm, visible_samples};
    use awl::image::DepthImage;
    use awl::mesh::TriMesh;
    use awl::normals::{NormalParams, with_normals};
    use awl::pipeline::FuseOutput;
    use awl::registration::{IcpLevel, IcpParams, register};
    use nalgebra::Isometry3;

    /// A fused model judged against the truth.
    pub struct Outcome {
        /// RMS distance of the on-object model points to the CAD (within 10 mm), mm.
        pub rmse_mm: f64,
        /// Visible CAD surface with a model point within 5 mm.
        pub completeness_5mm: f64,
        /// Model points farther than 10 mm from the CAD.
        pub off_object: f64,
        /// Trajectory error of the seeds, mm.
        pub seed_error_mm: f64,
        /// Trajectory error of the registered poses, mm.
        pub registered_error_mm: f64,
        /// `T_object_model`: the model's alignment onto the CAD (fine ICP from the true pose).
        pub object_from_model: Isometry3<f64>,
    }

    /// What the truth says about a scan.
    pub struct TruthScene<'a> {
        /// The CAD mesh (object frame).
        pub cad: &'a TriMesh,
        /// `T_world_object`.
        pub world_from_object: Isometry3<f64>,
        /// The depth camera.
        pub camera: DepthCamera,
        /// Per view: true `T_world_camera` and its depth image.
        pub views: Vec<(Isometry3<f64>, &'a DepthImage)>,
        /// Per view: the recorded (seed) `T_world_camera`.
        pub seeds: Vec<Isometry3<f64>>,
    }

    /// Mean camera-centre error after the best rigid alignment of the trajectory onto the truth, mm.
    pub fn trajectory_error(poses: &[Isometry3<f64>], truth: &[Isometry3<f64>]) -> f64 {
        trajectory_error_mm(poses, truth).expect("trajectory alignment")
    }

    /// Model against CAD (after aligning the model from the true pose, coarse to fine: the model frame
    /// carries the anchor view's seed error) and registered poses against the seeds.
    pub fn evaluate(scene: &TruthScene<'_>, out: &FuseOutput) -> Outcome {
        let cad = MeshDistance::new(scene.cad).expect("cad");
        let cad_cloud =
            with_normals(&scene.cad.sample_surface(200_000, 1).expect("sample"), &NormalParams::default(), None)
                .expect("cad normals");
        let object_from_world = scene.world_from_object.inverse();
        let mut fine = IcpParams::default();
        fine.levels.push(IcpLevel { voxel_m: 0.002, max_correspondence_m: 0.01, max_iterations: 50 });
        let aligned = register(&out.model, &cad_cloud, &object_from_world, &fine).expect("align");
        let model_object = out.model.transformed(&aligned.target_from_source);
        let samples = scene.cad.sample_surface(30_000, 2).expect("samples");
        let samples_world = samples.transformed(&scene.world_from_object);
        let visible =
            visible_samples(&samples_world, &scene.camera.intrinsics, scene.camera.depth_scale, &scene.views, 0.01);
        let keep: Vec<usize> = (0..samples.len()).filter(|&i| visible[i]).collect();
        let visible_samples: PointCloud = samples.select(&keep);
        let m = cad_metrics(&model_object, &cad, &visible_samples.points, 0.01, &[0.005]).expect("metrics");
        let merged: Vec<usize> = (0..out.poses.len()).filter(|&i| out.poses[i].is_some()).collect();
        let truth: Vec<Isometry3<f64>> = merged.iter().map(|&i| scene.views[i].0).collect();
        let seeds: Vec<Isometry3<f64>> = merged.iter().map(|&i| scene.seeds[i]).collect();
        let registered: Vec<Isometry3<f64>> = merged.iter().filter_map(|&i| out.poses[i]).collect();
        Outcome {
            rmse_mm: m.rmse_m * 1e3,
            completeness_5mm: m.completeness[0].1,
            off_object: m.off_object_fraction,
            seed_error_mm: trajectory_error(&seeds, &truth),
            registered_error_mm: trajectory_error(&registered, &truth),
            object_from_model: aligned.target_from_source,
        }
    }

    /// Issue 3's acceptance thresholds on a fused scan: RMSE <= 2 mm, completeness@5mm >= 95 %, off-object
    /// < 0.5 %, registered poses at least 5x closer to the truth than the seeds. Prints the numbers.
    pub fn assert_acceptance(label: &str, o: &Outcome, report: &awl::pipeline::FuseReport) {
        let merged = report.views.iter().filter(|v| v.pose.is_some()).count();
        let summary = format!(
            "{label}: RMSE {:.2} mm, completeness@5mm {:.1} %, off-object {:.2} %, trajectory {:.1} -> {:.2} mm, {merged} of {} views merged; warnings {:?}",
            o.rmse_mm,
            o.completeness_5mm * 100.0,
            o.off_object * 100.0,
            o.seed_error_mm,
            o.registered_error_mm,
            report.views.len(),
            report.warnings
        );
        println!("{summary}");
        assert!(o.rmse_mm <= 2.0, "{summary}");
        assert!(o.completeness_5mm >= 0.95, "{summary}");
        assert!(o.off_object < 0.005, "{summary}");
        assert!(o.registered_error_mm * 5.0 <= o.seed_error_mm, "{summary}");
    }
}
// not every test binary uses these
#[cfg(feature = "eval")]
#[allow(unused_imports)]
pub use against_truth::*;
