//! Named diagnoses of a calibration, and the pose-convention check: the closed form solved again
//! with every `T_base_ee`, every `T_camera_target`, or both inverted, to see whether the file holds
//! `T_ee_base` / `T_target_camera` instead.

use std::fmt;

use serde::Serialize;

use crate::handeye::HandEyePose;
use crate::handeye::motion::pose_pairs;
use crate::handeye::park;
use crate::handeye::residual::{implied_targets, median, residuals, robust_mean};

/// What a warning is about (serialised by its snake_case name, e.g. `scale_undetermined`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Diagnosis {
    /// The rotation axes of the motions span less than `min_axis_angle_deg`.
    PoorMotionDiversity,
    /// More poses look like outliers than `max_rejected_fraction` lets go.
    RejectionCapReached,
    /// The refinement stopped at its iteration cap.
    RefinementNotConverged,
    /// The predicted 95 % bound of the translation's error exceeds `tolerance_mm`.
    TranslationUndetermined,
    /// The target scale's 1-sigma exceeds `max_scale_sigma_percent`: a wrong tag size would pass
    /// unnoticed into the translation.
    ScaleUndetermined,
    /// The poses fit far better with a field inverted, accepted with `allow_inverted_fit`.
    InvertedConvention,
    /// The `T_camera_target` translations fit significantly better scaled by a factor other than 1:
    /// the tag or board size given to the detector is wrong.
    ScaleMismatch,
    /// The refinement left the closed forms' agreement by more than the noise explains; the result
    /// is the closed form.
    RefinementDisagrees,
}

impl Diagnosis {
    /// The name used in files (`poor_motion_diversity`, ...).
    pub fn name(self) -> &'static str {
        match self {
            Self::PoorMotionDiversity => "poor_motion_diversity",
            Self::RejectionCapReached => "rejection_cap_reached",
            Self::RefinementNotConverged => "refinement_not_converged",
            Self::TranslationUndetermined => "translation_undetermined",
            Self::ScaleUndetermined => "scale_undetermined",
            Self::InvertedConvention => "inverted_convention",
            Self::ScaleMismatch => "scale_mismatch",
            Self::RefinementDisagrees => "refinement_disagrees",
        }
    }
}

/// One non-fatal problem: what it is and a message saying what is wrong and what capture fixes it.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct HandEyeWarning {
    /// The kind of problem.
    pub diagnosis: Diagnosis,
    /// What is wrong, with the numbers, and what to change.
    pub message: String,
}

impl HandEyeWarning {
    pub(crate) fn new(diagnosis: Diagnosis, message: impl Into<String>) -> Self {
        Self { diagnosis, message: message.into() }
    }
}

impl fmt::Display for HandEyeWarning {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{} ({})", self.message, self.diagnosis.name())
    }
}

/// Which fields of every pose an inversion flips.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Inversion {
    /// Every `T_base_ee` inverted (the file would hold `T_ee_base`).
    BaseFromEe,
    /// Every `T_camera_target` inverted (the file would hold `T_target_camera`).
    CameraFromTarget,
    /// Both.
    Both,
}

impl Inversion {
    /// The field(s) as named in the poses file.
    pub fn fields(self) -> &'static str {
        match self {
            Self::BaseFromEe => "T_base_ee",
            Self::CameraFromTarget => "T_camera_target",
            Self::Both => "T_base_ee and T_camera_target",
        }
    }

    fn apply(self, p: &HandEyePose) -> HandEyePose {
        let (e, c) = (p.base_from_ee, p.camera_from_target);
        match self {
            Self::BaseFromEe => HandEyePose { base_from_ee: e.inverse(), camera_from_target: c },
            Self::CameraFromTarget => HandEyePose { base_from_ee: e, camera_from_target: c.inverse() },
            Self::Both => HandEyePose { base_from_ee: e.inverse(), camera_from_target: c.inverse() },
        }
    }
}

/// How well the poses fit with one inversion (Park-Martin closed form on all of them), and where
/// that solution puts the camera and the target.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct InversionFit {
    /// What was inverted.
    pub inversion: Inversion,
    /// Median translation residual over all poses, millimetres.
    pub median_translation_mm: f64,
    /// Median rotation residual over all poses, degrees.
    pub median_rotation_deg: f64,
    /// The solution's camera distance from the flange (`|t(T_ee_camera)|`), metres.
    pub camera_from_flange_m: f64,
    /// The solution's target distance from the robot base (`|t(T_base_target)|`), metres.
    pub target_from_base_m: f64,
}

/// The fit of each inversion whose closed form is solvable.
pub(crate) fn inversion_fits(poses: &[HandEyePose]) -> Vec<InversionFit> {
    let all: Vec<usize> = (0..poses.len()).collect();
    let every = vec![true; poses.len()];
    [Inversion::BaseFromEe, Inversion::CameraFromTarget, Inversion::Both]
        .into_iter()
        .filter_map(|inversion| {
            let flipped: Vec<HandEyePose> = poses.iter().map(|p| inversion.apply(p)).collect();
            let x = park::solve(&pose_pairs(&flipped)).ok()?;
            let targets = implied_targets(&flipped, &x);
            let target = robust_mean(&targets, &all);
            let res = residuals(&targets, &target, &every);
            let mut t: Vec<f64> = res.iter().map(|r| r.translation_mm).collect();
            let mut r: Vec<f64> = res.iter().map(|r| r.rotation_deg).collect();
            Some(InversionFit {
                inversion,
                median_translation_mm: median(&mut t),
                median_rotation_deg: median(&mut r),
                camera_from_flange_m: x.translation.vector.norm(),
                target_from_base_m: target.translation.vector.norm(),
            })
        })
        .collect()
}
