//! Scan-time advice (`report.json` `advice`): per base stop, how much [`EXTRA_VIEWS`] more views
//! there would gain for the hand-eye and for where the model of the region that stop looks at
//! sits from where the arm looks at it, and the stops where the views taken are not enough.
//!
//! The gain is predicted, not measured: the hand-eye refinement's system (`handeye::chain`) is
//! set up at the hand-eye used, every registered view moved onto it (so the residuals play no
//! part, only the geometry of the motions), once as the scan is and once per stop with
//! [`EXTRA_VIEWS`] views added there: the stop's first view turned [`TURN_DEG`] about its camera's
//! x axis and about its y axis, around the point it looks at (the views' common focus, at that
//! view's depth). Each added view is taken to leave the same motions unobserved as the stop's first.

use nalgebra::{Isometry3, Matrix3, Matrix6, Point3, Rotation3, Translation3, Unit, Vector3, Vector6};
use serde::{Deserialize, Serialize};

use super::hand_eye::{HandEyeConfig, HandEyeReport, base_stops};
use super::prepare::focus_point;
use crate::error::Result;
use crate::handeye::capture_bound::norm_quantile;
use crate::handeye::chain::{ChainParams, ChainPrior, ChainView, StopPrior, refine_chain_observed};
use crate::scan::{Scan, ViewPose};

/// The views added at a stop to predict its gain: 2.
pub const EXTRA_VIEWS: usize = 2;
/// How far each added view is turned about the point its stop looks at, degrees: 20.
pub const TURN_DEG: f64 = 20.0;
/// The stops of at most [`EXTRA_VIEWS`] views are named as not enough when the views added at all
/// of them together would cut the hand-eye's translation bound by at least this fraction: 0.25.
pub const NOT_ENOUGH_GAIN: f64 = 0.25;
/// Above this many base stops no advice is computed (one dense solve per stop): 64.
pub const MAX_STOPS: usize = 64;

/// The 95 % bounds of one stop, now and with [`EXTRA_VIEWS`] more views there.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StopAdvice {
    /// The base stop (`base_stop`, or its first view's index).
    pub stop: usize,
    /// Its registered views the hand-eye refinement used.
    pub views: usize,
    /// The point its views look at, world frame, metres (`null`: the views' axes meet nowhere).
    pub region_world: Option<[f64; 3]>,
    /// The hand-eye's 95 % translation bound, millimetres: now, then with the views added here.
    pub hand_eye_mm: [f64; 2],
    /// ... its rotation bound, degrees.
    pub hand_eye_deg: [f64; 2],
    /// The 95 % bound on how far the region's model sits from where the arm looks at it through
    /// the hand-eye (the hand-eye's error carried to the region at the first view's depth),
    /// millimetres: now, then with the views added here (`null` without a region).
    pub region_mm: Option<[f64; 2]>,
}

/// The advice of one scan.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ScanAdvice {
    /// The views added per stop in the prediction ([`EXTRA_VIEWS`]) and their turn, degrees.
    pub extra_views: usize,
    /// ... ([`TURN_DEG`]).
    pub turn_deg: f64,
    /// Every stop the refinement used, in stop order.
    pub stops: Vec<StopAdvice>,
    /// The stops of at most [`EXTRA_VIEWS`] views, when the views added at all of them together
    /// would gain at least [`NOT_ENOUGH_GAIN`]: the views taken there are not enough.
    pub not_enough: Vec<usize>,
    /// The stop where the added views would shrink the hand-eye's translation bound most.
    pub best_stop: Option<usize>,
    /// The hand-eye's 95 % translation bound (millimetres) and rotation bound (degrees) with the
    /// views added at every stop of at most [`EXTRA_VIEWS`] views together (`null`: none).
    pub together: Option<[f64; 2]>,
}

impl ScanAdvice {
    /// One line for the user: the stops named, with what views there would gain; `None` when no
    /// stop is named.
    pub fn summary(&self) -> Option<String> {
        let together = self.together.filter(|_| !self.not_enough.is_empty())?;
        let now = self.stops.first()?;
        let stops = if self.not_enough.len() == self.stops.len() {
            "every base stop".to_string()
        } else {
            format!("base stop(s) {:?}", self.not_enough)
        };
        let best = (self.best_stop.and_then(|b| self.stops.iter().find(|s| s.stop == b))).map_or(String::new(), |s| {
            format!("; {} more at stop {} alone: {:.1} mm", self.extra_views, s.stop, s.hand_eye_mm[1])
        });
        Some(format!(
            "scan advice: the views at {stops} are not enough for the hand-eye: its 95 % bound is {:.1} mm / {:.2} deg; \
             {} more views at each (turned {} deg about the camera's x and y axes around what it looks at) would \
             take it to {:.1} mm / {:.2} deg{best} (report.json advice)",
            now.hand_eye_mm[0], now.hand_eye_deg[0], self.extra_views, self.turn_deg, together[0], together[1]
        ))
    }
}

/// The 95 % bound of the norm of a 3D error of covariance `c` (metres or radians).
fn bound(c: &Matrix3<f64>) -> f64 {
    let e = c.symmetric_eigen().eigenvalues;
    norm_quantile([e[0].max(0.0), e[1].max(0.0), e[2].max(0.0)], 0.95)
}

/// The covariance of where a point `p` (camera frame, metres) sits from where the camera's
/// hand-eye places it, for a hand-eye of right-perturbation covariance `x` (`(ω, v)`, camera frame):
/// `δp = ω × p + v`.
fn point_covariance(x: &Matrix6<f64>, p: &Vector3<f64>) -> Matrix3<f64> {
    let mut j = nalgebra::Matrix3x6::zeros();
    j.fixed_view_mut::<3, 3>(0, 0).copy_from(&(-p.cross_matrix()));
    j.fixed_view_mut::<3, 3>(0, 3).copy_from(&Matrix3::identity());
    j * x * j.transpose()
}

/// The advice for `scan`, whose hand-eye refinement reported `report` from the registered `poses`
/// (`T_world_camera`, `None`: left out) and the views' `unobserved` motions (as for
/// `refine_hand_eye`); `None` when the refinement used no view or the scan has more than
/// [`MAX_STOPS`] stops.
///
/// # Errors
/// [`crate::error::Error::Invalid`] from the refinement's system (a setting that is not positive).
pub fn advise(
    scan: &Scan,
    report: &HandEyeReport,
    poses: &[Option<Isometry3<f64>>],
    unobserved: &[Vec<Vector6<f64>>],
    config: &HandEyeConfig,
) -> Result<Option<ScanAdvice>> {
    let (x, _) = report.used()?;
    let stops = base_stops(scan);
    // the views the refinement used (or, when it declined before choosing, every registered chain view)
    let chosen: Vec<usize> = if report.views_used.is_empty() {
        (0..scan.views.len()).filter(|&i| poses.get(i).is_some_and(Option::is_some) && stops[i].is_some()).collect()
    } else {
        report.views_used.clone()
    };
    let views: Vec<(usize, ChainView)> = (chosen.iter())
        .filter_map(|&i| match (scan.views[i].pose, stops[i]) {
            (ViewPose::Chain { world_from_base, base_from_ee }, Some(stop)) => Some((
                i,
                ChainView {
                    stop,
                    world_from_base,
                    base_from_ee,
                    model_from_camera: world_from_base * base_from_ee * x,
                },
            )),
            _ => None,
        })
        .collect();
    let mut stop_ids: Vec<usize> = views.iter().map(|(_, v)| v.stop).collect();
    stop_ids.sort_unstable();
    stop_ids.dedup();
    if views.is_empty() || stop_ids.len() > MAX_STOPS {
        return Ok(None);
    }
    let scale = report.residual_scale.max(1.0).powi(2);
    let prior = ChainPrior::isotropic(x, config.prior_sigma_m, config.prior_sigma_rad);
    let params = ChainParams {
        noise: config.noise,
        stops: config.stop_sigma.map_or(StopPrior::Free, StopPrior::Sigma),
        max_iterations: 5,
        prior_dof: None,
    };
    let left_out = |i: usize| unobserved.get(i).cloned().unwrap_or_default();
    let covariance = |extra: &[(usize, ChainView)]| -> Result<Matrix6<f64>> {
        let all: Vec<&(usize, ChainView)> = views.iter().chain(extra).collect();
        let chain: Vec<ChainView> = all.iter().map(|(_, v)| *v).collect();
        let twists: Vec<Vec<Vector6<f64>>> = all.iter().map(|(i, _)| left_out(*i)).collect();
        Ok(refine_chain_observed(&chain, &twists, &prior, &params)?.covariance * scale)
    };
    let translation = |c: &Matrix6<f64>| bound(&c.fixed_view::<3, 3>(3, 3).into_owned()) * 1e3;
    let rotation = |c: &Matrix6<f64>| bound(&c.fixed_view::<3, 3>(0, 0).into_owned()).to_degrees();
    let now = covariance(&[])?;
    let cameras: Vec<Isometry3<f64>> = views.iter().map(|(_, v)| v.model_from_camera).collect();
    let focus = focus_point(&cameras);
    let (mut advice, mut added) = (Vec::new(), Vec::new());
    for &stop in &stop_ids {
        let mine: Vec<&(usize, ChainView)> = views.iter().filter(|(_, v)| v.stop == stop).collect();
        let (first_index, first) = *mine[0];
        let camera = first.model_from_camera;
        let axis = camera.rotation * Vector3::z();
        // the point the view looks at: on its optical axis at the focus' depth
        let region = focus.map(|f| {
            Point3::from(camera.translation.vector + axis * (f.coords - camera.translation.vector).dot(&axis))
        });
        let pivot = region.unwrap_or_else(|| Point3::from(camera.translation.vector + axis));
        let extra: Vec<(usize, ChainView)> = [Vector3::x(), Vector3::y()]
            .iter()
            .take(EXTRA_VIEWS)
            .map(|a| {
                let turn = Rotation3::from_axis_angle(&Unit::new_normalize(camera.rotation * a), TURN_DEG.to_radians());
                let about = Translation3::from(pivot.coords)
                    * Isometry3::from_parts(Translation3::identity(), turn.into())
                    * Translation3::from(-pivot.coords);
                let turned = about * camera;
                let base_from_ee = first.world_from_base.inverse() * turned * x.inverse();
                (first_index, ChainView { base_from_ee, model_from_camera: turned, ..first })
            })
            .collect();
        let with = covariance(&extra)?;
        added.push(extra);
        let region_mm = region.map(|r| {
            let p = camera.inverse() * r;
            [bound(&point_covariance(&now, &p.coords)) * 1e3, bound(&point_covariance(&with, &p.coords)) * 1e3]
        });
        advice.push(StopAdvice {
            stop,
            views: mine.len(),
            region_world: region.map(|r| [r.x, r.y, r.z]),
            hand_eye_mm: [translation(&now), translation(&with)],
            hand_eye_deg: [rotation(&now), rotation(&with)],
            region_mm,
        });
    }
    // the stops of at most EXTRA_VIEWS views, all given the views at once
    let few: Vec<usize> = (advice.iter()).filter(|s| s.views <= EXTRA_VIEWS).map(|s| s.stop).collect();
    let named: Vec<(usize, ChainView)> = (stop_ids.iter().zip(&added))
        .filter(|(stop, _)| few.contains(*stop))
        .flat_map(|(_, extra)| extra.iter().copied())
        .collect();
    let together = match named.is_empty() {
        true => None,
        false => covariance(&named).map(|c| Some([translation(&c), rotation(&c)]))?,
    };
    let now_mm = translation(&now);
    let not_enough = match together {
        Some([mm, _]) if now_mm > 0.0 && 1.0 - mm / now_mm >= NOT_ENOUGH_GAIN => few,
        _ => Vec::new(),
    };
    let best_stop = (advice.iter()).min_by(|a, b| a.hand_eye_mm[1].total_cmp(&b.hand_eye_mm[1])).map(|s| s.stop);
    Ok(Some(ScanAdvice {
        extra_views: EXTRA_VIEWS,
        turn_deg: TURN_DEG,
        stops: advice,
        not_enough,
        best_stop,
        together,
    }))
}

#[cfg(test)]
mod tests {
    use nalgebra::{Translation3, UnitQuaternion};
    use serde_json::{Map, json};

    use super::*;
    use crate::pipeline::hand_eye::refine_hand_eye;
    use crate::random::{Stream, normal_perturbation, rng};
    use crate::scan::{ViewData, ViewSpec};

    /// The camera at `eye` looking at `at` (z forward), world frame.
    fn look_at(eye: Point3<f64>, at: Point3<f64>) -> Isometry3<f64> {
        let z = (at - eye).normalize();
        let x = z.cross(&Vector3::z()).normalize();
        let rotation = Rotation3::from_matrix_unchecked(Matrix3::from_columns(&[x, z.cross(&x), z]));
        Isometry3::from_parts(Translation3::from(eye.coords), rotation.into())
    }

    /// `camera` turned by `deg` about its own axis `axis` around the world point `pivot`.
    fn turned(camera: &Isometry3<f64>, axis: Vector3<f64>, deg: f64, pivot: Point3<f64>) -> Isometry3<f64> {
        let turn = UnitQuaternion::from_axis_angle(&Unit::new_normalize(camera.rotation * axis), deg.to_radians());
        Translation3::from(pivot.coords)
            * Isometry3::from_parts(Translation3::identity(), turn)
            * Translation3::from(-pivot.coords)
            * camera
    }

    fn truth() -> Isometry3<f64> {
        Isometry3::from_parts(
            Translation3::new(0.03, -0.02, 0.05),
            UnitQuaternion::from_scaled_axis(Vector3::new(0.0, 0.0, 1.57)),
        )
    }

    const OBJECT: Point3<f64> = Point3::new(0.0, 0.0, 0.15);

    /// Stop `s` stands on a circle around the object; its first camera looks at the object and
    /// each further one is the first turned 25 deg about the camera axis `turns[s][k]` around it.
    /// Registered exactly; the flange poses are the true chain's.
    fn scan(turns: &[Vec<Vector3<f64>>]) -> (Scan, Vec<Option<Isometry3<f64>>>) {
        let x = truth();
        let (mut views, mut poses) = (Vec::new(), Vec::new());
        for (s, axes) in turns.iter().enumerate() {
            let a = 1.3 * s as f64;
            let world_from_base = Isometry3::from_parts(
                Translation3::new(1.2 * a.cos(), 1.2 * a.sin(), 0.0),
                UnitQuaternion::from_axis_angle(&Vector3::z_axis(), a + std::f64::consts::PI),
            );
            let first = look_at(Point3::new(0.7 * a.cos(), 0.7 * a.sin(), 0.6), OBJECT);
            let cameras = std::iter::once(first).chain(axes.iter().map(|axis| turned(&first, *axis, 25.0, OBJECT)));
            for camera in cameras {
                views.push(chain_spec(s, world_from_base, world_from_base.inverse() * camera * x.inverse()));
                poses.push(Some(camera));
            }
        }
        let scan = Scan { dir: ".".into(), camera: None, ee_from_camera: Some(x), tag: None, views, warnings: vec![] };
        (scan, poses)
    }

    fn chain_spec(stop: usize, world_from_base: Isometry3<f64>, base_from_ee: Isometry3<f64>) -> ViewSpec {
        let mut extra = Map::new();
        extra.insert("base_stop".into(), json!(stop));
        ViewSpec {
            data: ViewData::Points { points: "v.ply".into() },
            pose: ViewPose::Chain { world_from_base, base_from_ee },
            extra,
        }
    }

    fn advice_of(scan: &Scan, poses: &[Option<Isometry3<f64>>], config: &HandEyeConfig) -> ScanAdvice {
        let report = refine_hand_eye(scan, poses, &[], config).expect("refine").expect("a report");
        advise(scan, &report, poses, &[], config).expect("advise").expect("advice")
    }

    #[test]
    fn stops_of_two_views_are_named_and_more_views_shrink_the_bounds() {
        let (x, y, z) = (Vector3::x(), Vector3::y(), Vector3::z());
        // every stop panning about its camera's y axis (near the vertical at every stop): the
        // hand-eye's height is poorly seen, and turns about x at the stops of two views would show it
        let (s, poses) = scan(&[vec![y], vec![y], vec![y], vec![y], vec![y], vec![y, -y]]);
        let a = advice_of(&s, &poses, &HandEyeConfig::default());
        for stop in &a.stops {
            println!("{stop:?}");
            assert!(stop.hand_eye_mm[1] < stop.hand_eye_mm[0] && stop.hand_eye_deg[1] < stop.hand_eye_deg[0]);
            let region = stop.region_mm.expect("the views look at one point");
            assert!(region[1] < region[0], "{region:?}");
            let at = stop.region_world.expect("region");
            assert!((Point3::from(at) - OBJECT).norm() < 1e-6, "{at:?}");
        }
        println!("{:?} {:?} {:?}", a.not_enough, a.together, a.summary());
        // the five stops of two views are named; the one of three is not, however much it would gain
        assert_eq!(a.not_enough, vec![0, 1, 2, 3, 4]);
        let together = a.together.expect("together");
        let best = a.stops.iter().map(|s| s.hand_eye_mm[1]).fold(f64::INFINITY, f64::min);
        assert!(together[0] < best, "{together:?} vs {best}");
        assert!(a.summary().expect("summary").contains("base stop(s) [0, 1, 2, 3, 4]"));
        // four views at every stop: nothing named, no summary
        let (s, poses) = scan(&[vec![x, y, z], vec![x, y, z], vec![y, z, x]]);
        let full = advice_of(&s, &poses, &HandEyeConfig::default());
        assert!(full.not_enough.is_empty() && full.together.is_none() && full.summary().is_none());
    }

    /// The 95 % quantile of the hand-eye translation error of `refine_hand_eye` over noisy draws of
    /// `scan` (the flanges and the recorded hand-eye drawn at `config`'s sigmas), millimetres.
    fn monte_carlo(scan: &Scan, poses: &[Option<Isometry3<f64>>], config: &HandEyeConfig, draws: u64) -> f64 {
        let n = &config.noise;
        let (st, sr) =
            ((n.arm_m.powi(2) + n.camera_m.powi(2)).sqrt(), (n.arm_rad.powi(2) + n.camera_rad.powi(2)).sqrt());
        let mut errors: Vec<f64> = (0..draws)
            .map(|k| {
                let mut r = rng(7, Stream::PoseNoise, k, 0);
                let mut noisy = scan.clone();
                noisy.ee_from_camera =
                    Some(truth() * normal_perturbation(&mut r, config.prior_sigma_m, config.prior_sigma_rad));
                for v in &mut noisy.views {
                    if let ViewPose::Chain { base_from_ee, .. } = &mut v.pose {
                        *base_from_ee *= normal_perturbation(&mut r, st, sr);
                    }
                }
                let report = refine_hand_eye(&noisy, poses, &[], config).expect("refine").expect("report");
                let (refined, _) = report.used().expect("rigid");
                (truth().inverse() * refined).translation.vector.norm() * 1e3
            })
            .collect();
        errors.sort_by(f64::total_cmp);
        errors[(0.95 * draws as f64) as usize]
    }

    #[test]
    fn the_predicted_gain_is_what_the_refinement_reaches() {
        // a Gaussian prior and free stops: the refinement is the linear estimator the bound describes
        let config = HandEyeConfig { prior_dof: None, stop_sigma: None, ..HandEyeConfig::default() };
        let (x, y, z) = (Vector3::x(), Vector3::y(), Vector3::z());
        let (s, poses) = scan(&[vec![x], vec![y], vec![z]]);
        let before = advice_of(&s, &poses, &config);
        // the two views the advice describes, taken at stop 0
        let (mut more, mut more_poses) = (s.clone(), poses.clone());
        let ViewPose::Chain { world_from_base, .. } = s.views[0].pose else { panic!("a chain view") };
        let first = poses[0].expect("registered");
        for axis in [x, y] {
            let camera = turned(&first, axis, TURN_DEG, OBJECT);
            more.views.push(chain_spec(0, world_from_base, world_from_base.inverse() * camera * truth().inverse()));
            more_poses.push(Some(camera));
        }
        let after = advice_of(&more, &more_poses, &config);
        let (predicted, reached) = (before.stops[0].hand_eye_mm[1], after.stops[0].hand_eye_mm[0]);
        assert!(
            (predicted / reached - 1.0).abs() < 0.01,
            "predicted {predicted:.3} mm, with the views {reached:.3} mm"
        );
        // both bounds against the refinement's errors over 400 noisy draws (sampling error of a 95 %
        // quantile: about 5 %)
        for (name, scan, poses, bound) in
            [("as taken", &s, &poses, before.stops[0].hand_eye_mm[0]), ("with 2 more", &more, &more_poses, reached)]
        {
            let q95 = monte_carlo(scan, poses, &config, 400);
            println!("{name}: bound {bound:.3} mm, refinement's 95 % error {q95:.3} mm");
            assert!((q95 / bound - 1.0).abs() < 0.12, "{name}: bound {bound:.3} mm, 95 % of errors under {q95:.3} mm");
        }
    }
}
