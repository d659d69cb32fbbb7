//! Isolating the object in the merged model: the floor plane goes, then the DBSCAN cluster of the
//! object stays (the largest, or the one holding a user-given seed point).

use nalgebra::Point3;

use super::config::IsolateConfig;
use super::report::{ClusterReport, FloorReport};
use crate::cloud::PointCloud;
use crate::cluster::dbscan;
use crate::error::{Error, Result};
use crate::segment::remove_floor;
use crate::spatial::brute;

/// Removes the floor; returns the rest and what was found. A scan without a floor plane is not an
/// error: the cloud comes back whole and the warning says so.
pub(crate) fn drop_floor(
    cloud: PointCloud,
    config: &IsolateConfig,
    warnings: &mut Vec<String>,
) -> Result<(PointCloud, Option<FloorReport>)> {
    if !config.remove_floor || cloud.len() < 3 {
        return Ok((cloud, None));
    }
    match remove_floor(&cloud.points, &config.floor, None) {
        Ok(removal) => {
            let removed = cloud.len() - removal.kept.len();
            let n = removal.floor.normal;
            let report = FloorReport { normal: [n.x, n.y, n.z], offset_m: removal.floor.offset_m, removed };
            if 2 * removed > cloud.len() {
                warnings.push(format!(
                    "floor removal took {removed} of {} points ({:.0} %), everything within {} mm of the plane: if that cut \
                     into the object, lower `isolate.floor.plane.distance_m` or set `isolate.remove_floor = false`",
                    cloud.len(),
                    100.0 * removed as f64 / cloud.len() as f64,
                    config.floor.plane.distance_m * 1e3
                ));
            }
            Ok((cloud.select(&removal.kept), Some(report)))
        }
        Err(e) => {
            warnings.push(format!("floor removal found no floor, model kept whole: {e}"));
            Ok((cloud, None))
        }
    }
}

/// Keeps the object's cluster.
///
/// # Errors
/// DBSCAN's errors; [`Error::Invalid`] for a seed point that is not finite.
pub(crate) fn keep_object(
    cloud: PointCloud,
    config: &IsolateConfig,
    warnings: &mut Vec<String>,
) -> Result<(PointCloud, Option<ClusterReport>)> {
    if !config.cluster || cloud.is_empty() {
        return Ok((cloud, None));
    }
    let clustering = dbscan(&cloud.points, &config.dbscan)?;
    let chosen = match config.seed_point {
        Some(p) => {
            if !p.iter().all(|v| v.is_finite()) {
                return Err(Error::invalid("isolate.seed_point", format!("{p:?} is not a finite point")));
            }
            let q = Point3::new(p[0] as f32, p[1] as f32, p[2] as f32);
            // one query: a scan, no tree
            brute::nearest(&cloud.points, &q).and_then(|n| usize::try_from(clustering.labels[n.index as usize]).ok())
        }
        None => clustering.largest(),
    };
    let Some(label) = chosen else {
        warnings.push("clustering found no cluster for the object; model kept whole".into());
        return Ok((cloud, None));
    };
    let members = clustering.members(label);
    if config.seed_point.is_none() && 2 * members.len() < cloud.len() {
        warnings.push(format!(
            "clustering kept {} of {} points ({:.0} %), the largest of {} clusters: if the object is in pieces, raise \
             `isolate.dbscan.eps_m` (now {} mm), give `isolate.seed_point`, or set `isolate.cluster = false`",
            members.len(),
            cloud.len(),
            100.0 * members.len() as f64 / cloud.len() as f64,
            clustering.cluster_count(),
            config.dbscan.eps_m * 1e3
        ));
    }
    let report = ClusterReport {
        clusters: clustering.cluster_count(),
        kept: members.len(),
        removed_clusters: clustering.labels.len() - members.len() - clustering.noise_count(),
        noise: clustering.noise_count(),
    };
    Ok((cloud.select(&members), Some(report)))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Two lattice patches 2 mm apart inside, 0.5 m from each other: 400 and 100 points.
    fn two_patches() -> PointCloud {
        let patch = |n: usize, x0: f32| {
            (0..n * n).map(move |k| Point3::new(x0 + 0.002 * (k % n) as f32, 0.002 * (k / n) as f32, 0.0))
        };
        PointCloud::from_points(patch(20, 0.0).chain(patch(10, 0.5)).collect())
    }

    #[test]
    fn keeps_the_largest_cluster_or_the_one_at_the_seed_point() {
        let config = IsolateConfig { remove_floor: false, ..IsolateConfig::default() };
        let mut warnings = Vec::new();
        let (largest, report) = keep_object(two_patches(), &config, &mut warnings).expect("largest");
        assert_eq!((largest.len(), report.map(|r| r.clusters)), (400, Some(2)));
        // the seed point is off the model: its nearest model point decides
        let seeded = IsolateConfig { seed_point: Some([0.52, 0.01, 0.05]), ..config };
        let (picked, report) = keep_object(two_patches(), &seeded, &mut warnings).expect("seeded");
        assert_eq!((picked.len(), report.map(|r| r.removed_clusters)), (100, Some(400)));
        assert!(picked.points.iter().all(|p| p.x >= 0.5));
        assert!(warnings.is_empty(), "{warnings:?}");
        // the largest of three similar clusters is under half the points: said, with the keys to change
        let mut three = two_patches();
        three.points.truncate(400);
        three.points.extend((0..300).map(|k| Point3::new(1.0 + 0.002 * (k % 15) as f32, 0.002 * (k / 15) as f32, 0.0)));
        three.points.extend((0..300).map(|k| Point3::new(2.0 + 0.002 * (k % 15) as f32, 0.002 * (k / 15) as f32, 0.0)));
        let (kept, _) = keep_object(three, &config, &mut warnings).expect("three");
        assert_eq!(kept.len(), 400);
        assert_eq!(warnings.len(), 1, "{warnings:?}");
        assert!(
            warnings[0].contains("kept 400 of 1000 points") && warnings[0].contains("isolate.dbscan.eps_m"),
            "{warnings:?}"
        );
        let bad = IsolateConfig { seed_point: Some([f64::NAN, 0.0, 0.0]), ..config };
        let e = keep_object(two_patches(), &bad, &mut warnings).expect_err("NaN seed point").to_string();
        assert!(e.contains("isolate.seed_point"), "{e}");
    }

    /// A floor of 2500 points under a 400-point object: taking most of the points is said, with the key.
    #[test]
    fn floor_taking_most_points_is_said() {
        let mut points: Vec<Point3<f32>> =
            (0..2500).map(|k| Point3::new(0.01 * (k % 50) as f32, 0.01 * (k / 50) as f32, 0.0)).collect();
        points
            .extend((0..400).map(|k| Point3::new(0.2 + 0.002 * (k % 20) as f32, 0.2, 0.05 + 0.002 * (k / 20) as f32)));
        let mut warnings = Vec::new();
        let (rest, report) =
            drop_floor(PointCloud::from_points(points), &IsolateConfig::default(), &mut warnings).expect("floor");
        assert_eq!((rest.len(), report.map(|r| r.removed)), (400, Some(2500)));
        assert_eq!(warnings.len(), 1, "{warnings:?}");
        assert!(
            warnings[0].contains("took 2500 of 2900 points") && warnings[0].contains("isolate.floor.plane.distance_m"),
            "{warnings:?}"
        );
    }
}
