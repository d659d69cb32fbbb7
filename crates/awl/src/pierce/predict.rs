//! The error each target may have before the tool moves, and the go / no-go gate.
//!
//! A target's position error in the base frame comes from two places:
//! - the located `T_base_model` ([`crate::pierce::Located::base_from_model_covariance`]: the
//!   hand-eye, the arm's kinematic noise at the shot's views, the views' registration or the tag's
//!   corners), carried to the target point;
//! - the model at the target: its surface's error along the normal ([`PredictParams::model_sigma_m`])
//!   and, for a face centre, the centre's error in the face plane
//!   ([`PredictParams::face_centre_sigma_m`]).
//!
//! The tool axis errs by the located rotation (about the axes across it) and by the model's normal
//! there: [`TargetGeometry::normal_covariance_model`], from the scatter and extent of the patch that
//! gave it ([`crate::workpiece::SurfaceTarget::normal_covariance`]); along the tag's axis, by
//! [`PredictParams::axis_sigma_rad`]. Each bound is the norm's quantile at
//! [`PredictParams::confidence`] under that Gaussian (the covariance's eigenvalues, a fixed table of
//! seeded standard-normal draws: deterministic). The defaults are calibrated in BENCHMARKS.md.

use std::sync::OnceLock;

use nalgebra::{Isometry3, Matrix3, Matrix6, Point3, SymmetricEigen, Vector3};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::handeye::chain::point_covariance;

/// The model's share of each target's error, and the bounds' probability.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PredictParams {
    /// The model surface's error along its normal at a target, 1-sigma, metres.
    pub model_sigma_m: f64,
    /// A face centre's error in the face plane, 1-sigma per in-plane axis, metres.
    pub face_centre_sigma_m: f64,
    /// The tag axis' error on the model, 1-sigma about each axis across it, radians (the axis
    /// `tag`; a surface normal's error comes from its patch).
    pub axis_sigma_rad: f64,
    /// The probability a bound holds (0.95: a 95 % bound).
    pub confidence: f64,
}

impl Default for PredictParams {
    fn default() -> Self {
        Self {
            model_sigma_m: 0.0004,
            face_centre_sigma_m: 0.0004,
            axis_sigma_rad: 0.25f64.to_radians(),
            confidence: 0.95,
        }
    }
}

impl PredictParams {
    /// Checks every field is finite and in range.
    ///
    /// # Errors
    /// [`Error::Invalid`] naming the field.
    pub fn validate(&self) -> Result<()> {
        for (name, v) in [
            ("predict.model_sigma_m", self.model_sigma_m),
            ("predict.face_centre_sigma_m", self.face_centre_sigma_m),
            ("predict.axis_sigma_rad", self.axis_sigma_rad),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(Error::invalid(name, format!("{v} is not a non-negative number")));
            }
        }
        if !(self.confidence > 0.5 && self.confidence < 1.0) {
            return Err(Error::invalid("predict.confidence", format!("{} is not in (0.5, 1)", self.confidence)));
        }
        Ok(())
    }
}

/// How far off a target may be.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Prediction {
    /// Covariance of the target point's error, base frame, m².
    pub position_covariance: Matrix3<f64>,
    /// Covariance of the tool axis' error as a rotation vector across the axis, base frame, rad².
    pub axis_covariance: Matrix3<f64>,
    /// The bound on the position error at [`PredictParams::confidence`], metres.
    pub position_bound_m: f64,
    /// The bound on the axis error at [`PredictParams::confidence`], radians.
    pub axis_bound_rad: f64,
}

/// What is known of one target, for [`predict`].
#[derive(Debug, Clone, Copy)]
pub struct TargetGeometry {
    /// The target point, model frame.
    pub p_model: Point3<f64>,
    /// The outward surface normal there, model frame (unit).
    pub normal_model: Vector3<f64>,
    /// The piercing direction, base frame (unit).
    pub axis_base: Vector3<f64>,
    /// Whether it is a face centre (its in-plane position is estimated).
    pub face_centre: bool,
    /// The axis' error on the model as a rotation vector across it, model frame, rad²: the surface
    /// normal's ([`crate::workpiece::SurfaceTarget::normal_covariance`]) or, for the tag's axis,
    /// [`PredictParams::axis_sigma_rad`] about both axes across it.
    pub normal_covariance_model: Matrix3<f64>,
    /// How far apart the fuse found parts of the model (`hand_eye.rejected_disagreement_mm` of
    /// workpiece.json), metres: half of it is added as an isotropic 1-sigma (0: none).
    pub model_disagreement_m: f64,
}

/// The prediction for one target located by `base_from_model`, whose error covariance is
/// `covariance` (base frame, `(ω, v)`, rad² and m²: `T_base_model_true = exp(-(ω, v)) *
/// T_base_model`).
pub fn predict(
    base_from_model: &Isometry3<f64>,
    covariance: &Matrix6<f64>,
    target: &TargetGeometry,
    params: &PredictParams,
) -> Prediction {
    let n = base_from_model.rotation * target.normal_model;
    let along = n * n.transpose();
    let across = Matrix3::identity() - along;
    let mut position_covariance = point_covariance(&base_from_model.inverse(), covariance, &target.p_model)
        + along * params.model_sigma_m.powi(2);
    if target.face_centre {
        position_covariance += across * params.face_centre_sigma_m.powi(2);
    }
    position_covariance += Matrix3::identity() * (0.5 * target.model_disagreement_m).powi(2);
    // the axis turns by the rotation's components across it
    let a = target.axis_base;
    let across_axis = Matrix3::identity() - a * a.transpose();
    let omega = covariance.fixed_view::<3, 3>(0, 0).into_owned();
    let r = base_from_model.rotation.to_rotation_matrix().into_inner();
    let normal = r * target.normal_covariance_model * r.transpose();
    let axis_covariance = across_axis * (omega + normal) * across_axis.transpose();
    Prediction {
        position_covariance,
        axis_covariance,
        position_bound_m: norm_quantile(&position_covariance, params.confidence),
        axis_bound_rad: norm_quantile(&axis_covariance, params.confidence),
    }
}

/// Draws of the quantile table (its resolution: the 95 % quantile to about 0.5 %).
const DRAWS: usize = 20_000;

fn draws() -> &'static [[f64; 3]] {
    static TABLE: OnceLock<Vec<[f64; 3]>> = OnceLock::new();
    TABLE.get_or_init(|| {
        let mut rng = ChaCha8Rng::seed_from_u64(0x5eed_b0d5);
        (0..DRAWS)
            .map(|_| {
                let mut z = [0.0; 3];
                for c in &mut z {
                    *c = StandardNormal.sample(&mut rng);
                }
                z
            })
            .collect()
    })
}

/// The `confidence` quantile of `|x|` for `x ~ N(0, covariance)` (3-D; any rank), in the
/// covariance's unit's square root.
pub fn norm_quantile(covariance: &Matrix3<f64>, confidence: f64) -> f64 {
    let sym = (covariance + covariance.transpose()) * 0.5;
    if !sym.iter().all(|v| v.is_finite()) {
        return f64::INFINITY;
    }
    let l = SymmetricEigen::new(sym).eigenvalues.map(|v| v.max(0.0));
    let mut r2: Vec<f64> =
        draws().iter().map(|z| l[0] * z[0] * z[0] + l[1] * z[1] * z[1] + l[2] * z[2] * z[2]).collect();
    let k = ((confidence.clamp(0.0, 1.0) * DRAWS as f64).ceil() as usize).clamp(1, DRAWS) - 1;
    let (_, v, _) = r2.select_nth_unstable_by(k, f64::total_cmp);
    v.sqrt()
}

/// The most a target may be off for the tool to go.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Tolerance {
    /// The largest position bound allowed, metres (`None`: any).
    pub position_m: Option<f64>,
    /// The largest axis bound allowed, radians (`None`: any).
    pub axis_rad: Option<f64>,
}

impl Tolerance {
    /// Checks each given tolerance is a positive, finite number.
    ///
    /// # Errors
    /// [`Error::Invalid`] naming `--tolerance-mm` or `--tolerance-deg`.
    pub fn validate(&self) -> Result<()> {
        for (name, v) in [("--tolerance-mm", self.position_m), ("--tolerance-deg", self.axis_rad)] {
            if let Some(v) = v
                && !(v.is_finite() && v > 0.0)
            {
                return Err(Error::invalid(name, "the tolerance must be a positive number"));
            }
        }
        Ok(())
    }

    /// `None` when `prediction` is within the tolerance, else why not. A bound that is not finite
    /// is always refused, with or without a tolerance: nothing bounds where the tool would go.
    pub fn refusal(&self, prediction: &Prediction) -> Option<String> {
        let mut why = Vec::new();
        for (what, v) in [("position", prediction.position_bound_m), ("axis", prediction.axis_bound_rad)] {
            if !v.is_finite() {
                why.push(format!(
                    "the predicted {what} error has no finite bound (the located pose is unconstrained): take a \
                     shot whose views see the tag and the workpiece's surface from two directions"
                ));
            }
        }
        if !why.is_empty() {
            return Some(why.join("; "));
        }
        if let Some(t) = self.position_m.filter(|t| !(prediction.position_bound_m <= *t)) {
            why.push(format!(
                "the predicted position error {:.2} mm exceeds the tolerance {:.2} mm",
                prediction.position_bound_m * 1e3,
                t * 1e3
            ));
        }
        if let Some(t) = self.axis_rad.filter(|t| !(prediction.axis_bound_rad <= *t)) {
            why.push(format!(
                "the predicted axis error {:.2} deg exceeds the tolerance {:.2} deg",
                prediction.axis_bound_rad.to_degrees(),
                t.to_degrees()
            ));
        }
        (!why.is_empty()).then(|| why.join("; "))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantiles_match_the_chi_distributions() {
        // 3-D isotropic: sqrt(chi2_3(0.95)) = 2.7955; 1-D: 1.9600; 2-D: sqrt(5.9915) = 2.4477
        let q3 = norm_quantile(&Matrix3::identity(), 0.95);
        assert!((q3 - 2.7955).abs() < 0.02, "{q3}");
        let q1 = norm_quantile(&Matrix3::from_diagonal(&Vector3::new(0.0, 4.0, 0.0)), 0.95);
        assert!((q1 - 2.0 * 1.96).abs() < 0.04, "{q1}");
        let q2 = norm_quantile(&Matrix3::from_diagonal(&Vector3::new(1.0, 0.0, 1.0)), 0.95);
        assert!((q2 - 2.4477).abs() < 0.02, "{q2}");
        assert!(norm_quantile(&Matrix3::from_element(f64::NAN), 0.95).is_infinite());
    }

    #[test]
    fn a_rotation_error_grows_with_the_lever_arm_and_the_model_adds_its_share() {
        let mut c = Matrix6::zeros();
        c[(2, 2)] = 0.001f64.powi(2); // 1 mrad about base z
        let params = PredictParams { model_sigma_m: 0.0, face_centre_sigma_m: 0.0, ..PredictParams::default() };
        let target = |x: f64| TargetGeometry {
            p_model: Point3::new(x, 0.0, 0.0),
            normal_model: Vector3::z(),
            axis_base: -Vector3::z(),
            face_centre: false,
            normal_covariance_model: Matrix3::identity() * PredictParams::default().axis_sigma_rad.powi(2),
            model_disagreement_m: 0.0,
        };
        let near = predict(&Isometry3::identity(), &c, &target(0.1), &params);
        let far = predict(&Isometry3::identity(), &c, &target(1.0), &params);
        // a 1-D error (along y) of 0.1 mm and 1 mm sigma
        assert!((near.position_bound_m - 1.96e-4).abs() < 4e-6, "{}", near.position_bound_m);
        assert!((far.position_bound_m - 1.96e-3).abs() < 4e-5, "{}", far.position_bound_m);
        // a rotation about the tool axis does not turn it: only the model's normal counts
        let expected = params.axis_sigma_rad * 2.4477;
        assert!((far.axis_bound_rad - expected).abs() < 0.02 * expected, "{}", far.axis_bound_rad);
        let face = predict(
            &Isometry3::identity(),
            &Matrix6::zeros(),
            &TargetGeometry { face_centre: true, ..target(0.3) },
            &PredictParams::default(),
        );
        let d = PredictParams::default();
        // isotropic when both model sigmas are equal
        assert!((face.position_bound_m - 2.7955 * d.model_sigma_m).abs() < 0.02 * d.model_sigma_m);
        // a model whose parts the fuse found 18 mm apart: half of it a 1-sigma in every direction
        let split = predict(
            &Isometry3::identity(),
            &Matrix6::zeros(),
            &TargetGeometry { model_disagreement_m: 0.018, ..target(0.3) },
            &params,
        );
        assert!((split.position_bound_m - 2.7955 * 0.009).abs() < 0.02 * 0.025, "{}", split.position_bound_m);
    }

    #[test]
    fn the_gate_names_what_it_refuses() {
        let p = Prediction {
            position_covariance: Matrix3::zeros(),
            axis_covariance: Matrix3::zeros(),
            position_bound_m: 0.003,
            axis_bound_rad: 0.5f64.to_radians(),
        };
        let t = Tolerance { position_m: Some(0.002), axis_rad: Some(1f64.to_radians()) };
        let why = t.refusal(&p).expect("refused");
        assert!(why.contains("3.00 mm exceeds the tolerance 2.00 mm") && !why.contains("axis"), "{why}");
        assert!(Tolerance { position_m: Some(0.004), ..t }.refusal(&p).is_none());
        assert!(Tolerance { position_m: Some(-1.0), axis_rad: None }.validate().is_err());
        assert!(Tolerance { position_m: None, axis_rad: Some(f64::NAN) }.validate().is_err());
        let nan = Prediction { position_bound_m: f64::NAN, ..p };
        assert!(Tolerance { position_m: Some(0.01), axis_rad: None }.refusal(&nan).is_some());
        // without any tolerance, a bound that is not finite is still no-go, naming the cause
        for bad in [Prediction { position_bound_m: f64::INFINITY, ..p }, Prediction { axis_bound_rad: f64::NAN, ..p }] {
            let why = Tolerance::default().refusal(&bad).expect("an unbounded prediction is no-go");
            assert!(why.contains("no finite bound") && why.contains("two directions"), "{why}");
        }
        assert!(Tolerance::default().refusal(&p).is_none());
    }
}
