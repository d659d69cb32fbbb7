//! Pairwise registration on real scans with ground truth: the Stanford bunny (bun000/045/090 and
//! bun.conf, whose quaternion is scalar-last and applied conjugated: see shared/data/SOURCES.md).
//! Seeds are the truth perturbed by 25 mm / 5 deg (rotation about the source centroid, shift in a
//! random direction), 10 seeds per pair; every run must land within 1 mm and 0.5 deg.

mod common;

use awl::PointCloud;
use awl::io::ply::read_ply;
use awl::normals::{NormalParams, estimate};
use awl::registration::{IcpParams, register};
use nalgebra::{Isometry3, Point3, Quaternion, Translation3, UnitQuaternion, Vector3};
use rand::{RngExt, SeedableRng};

fn data_dir() -> std::path::PathBuf {
    common::shared_data().join("stanford_bunny")
}

/// `common_from_scan` for every `bmesh` line of bun.conf.
fn conf_poses() -> Vec<(String, Isometry3<f64>)> {
    let text = std::fs::read_to_string(data_dir().join("bun.conf")).expect("bun.conf");
    text.lines()
        .filter_map(|line| {
            let f: Vec<&str> = line.split_whitespace().collect();
            if f.first() != Some(&"bmesh") {
                return None;
            }
            let v: Vec<f64> = f[2..9].iter().map(|s| s.parse().expect("number")).collect();
            let q = UnitQuaternion::from_quaternion(Quaternion::new(v[6], v[3], v[4], v[5]));
            Some((f[1].to_string(), Isometry3::from_parts(Translation3::new(v[0], v[1], v[2]), q.inverse())))
        })
        .collect()
}

fn load(name: &str) -> PointCloud {
    let mut cloud = read_ply(&data_dir().join(name)).expect("bunny scan");
    let normals = estimate(&cloud.points, &NormalParams { neighbors: 20, radius_m: Some(0.005) }).expect("n");
    let keep = normals.valid_indices();
    cloud.normals = Some(normals.normals);
    cloud.select(&keep)
}

fn centroid(cloud: &PointCloud) -> Vector3<f64> {
    cloud.points.iter().fold(Vector3::zeros(), |a, p| a + p.coords.cast::<f64>()) / cloud.len() as f64
}

fn perturbation(rng: &mut impl RngExt, c: &Vector3<f64>, shift_m: f64, angle_rad: f64) -> Isometry3<f64> {
    let unit = |rng: &mut dyn FnMut() -> f64| Vector3::new(rng(), rng(), rng()).normalize();
    let mut gauss = || rng.random::<f64>() * 2.0 - 1.0;
    let axis = unit(&mut gauss);
    let dir = unit(&mut gauss);
    let r = UnitQuaternion::from_scaled_axis(axis * angle_rad);
    Isometry3::from_parts(Translation3::from(c - r * c + dir * shift_m), r)
}

#[test]
fn bunny_pairs_from_25mm_5deg_seeds() {
    let poses = conf_poses();
    let pose = |n: &str| poses.iter().find(|(f, _)| f == n).map(|(_, p)| *p).expect("pose in bun.conf");
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(2026);
    let mut worst = (0.0f64, 0.0f64);
    for (src, tgt) in [("bun045.ply", "bun000.ply"), ("bun090.ply", "bun045.ply"), ("bun090.ply", "bun000.ply")] {
        let (source, target) = (load(src), load(tgt));
        let truth = pose(tgt).inverse() * pose(src);
        let c = centroid(&source);
        for trial in 0..10 {
            let init = truth * perturbation(&mut rng, &c, 0.025, 5f64.to_radians());
            let result = register(&source, &target, &init, &IcpParams::default()).expect("registration");
            let est = result.target_from_source;
            let angle = (truth.inverse() * est).rotation.angle().to_degrees();
            let shift = ((est * Point3::from(c)) - (truth * Point3::from(c))).norm() * 1e3;
            worst = (worst.0.max(shift), worst.1.max(angle));
            assert!(
                shift < 1.0 && angle < 0.5,
                "{src}->{tgt} trial {trial}: {shift:.3} mm, {angle:.3} deg off (fitness {:.3}, rmse {:.3} mm, levels {:?})",
                result.fitness,
                result.inlier_rmse_m * 1e3,
                result.levels
            );
        }
    }
    println!("worst error over 30 runs: {:.3} mm, {:.3} deg", worst.0, worst.1);
}

#[test]
fn pre_down_sampled_target_levels_give_the_same_registration() {
    // register_levels with the target down-sampled at each level is register, bit for bit; a
    // wrong number of levels is an error
    use awl::filter::voxel::{VoxelParams, downsample};
    use awl::registration::register_levels;
    let poses = conf_poses();
    let pose = |n: &str| poses.iter().find(|(f, _)| f == n).map(|(_, p)| *p).expect("pose in bun.conf");
    let (source, target) = (load("bun045.ply"), load("bun000.ply"));
    let truth = pose("bun000.ply").inverse() * pose("bun045.ply");
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
    let init = truth * perturbation(&mut rng, &centroid(&source), 0.02, 4f64.to_radians());
    let params = IcpParams::default();
    let levels: Vec<PointCloud> = params
        .levels
        .iter()
        .map(|l| downsample(&target, &VoxelParams { voxel_size_m: l.voxel_m }).expect("level"))
        .collect();
    let refs: Vec<&PointCloud> = levels.iter().collect();
    let a = register(&source, &target, &init, &params).expect("register");
    let b = register_levels(&source, &refs, &init, &params).expect("register_levels");
    assert_eq!(a.target_from_source, b.target_from_source);
    assert_eq!(a.levels, b.levels);
    let shift =
        ((b.target_from_source * Point3::from(centroid(&source))) - (truth * Point3::from(centroid(&source)))).norm();
    assert!(shift < 1e-3, "{:.3} mm off the truth", shift * 1e3);
    assert!(register_levels(&source, &refs[1..], &init, &params).is_err());
}
