//! Isolating the object in the merged model: the floor plane goes, then the DBSCAN cluster of the
//! object stays (the largest, or the one holding a user-given seed point).

use nalgebra::Point3;

use super::config::IsolateConfig;
use super::report::{ClusterReport, FloorReport};
use crate::cloud::PointCloud;
use crate::cluster::dbscan;
use crate::error::Result;
use crate::segment::remove_floor;
use crate::spatial::KdIndex;

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
            Ok((cloud.select(&removal.kept), Some(report)))
        }
        Err(e) => {
            warnings.push(format!("floor removal found no floor, model kept whole: {e}"));
            Ok((cloud, None))
        }
    }
}

/// Keeps the object's cluster.
pub(crate) fn keep_object(
    cloud: PointCloud,
    config: &IsolateConfig,
    warnings: &mut Vec<String>,
) -> Result<(PointCloud, Option<ClusterReport>)> {
    if !config.cluster || cloud.is_empty() {
        return Ok((cloud, None));
    }
    let index = KdIndex::new(&cloud.points)?;
    let clustering = dbscan(&cloud.points, &index, &config.dbscan)?;
    let chosen = match config.seed_point {
        Some(p) => {
            let q = Point3::new(p[0] as f32, p[1] as f32, p[2] as f32);
            index.nearest(&q).and_then(|n| usize::try_from(clustering.labels[n.index as usize]).ok())
        }
        None => clustering.largest(),
    };
    let Some(label) = chosen else {
        warnings.push("clustering found no cluster for the object; model kept whole".into());
        return Ok((cloud, None));
    };
    let members = clustering.members(label);
    let report = ClusterReport {
        clusters: clustering.cluster_count(),
        kept: members.len(),
        removed_clusters: clustering.labels.len() - members.len() - clustering.noise_count(),
        noise: clustering.noise_count(),
    };
    Ok((cloud.select(&members), Some(report)))
}
