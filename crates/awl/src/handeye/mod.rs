//! Hand-eye calibration of the eye-in-hand camera: solves `A X = X B` for `X = ee_from_camera`
//! (`T_ee_camera` in files) from N robot poses `base_from_ee_i` (forward kinematics) and N
//! observations `camera_from_target_i` of a target (tag or board) fixed in the base frame.
//!
//! Every pair `i < j` of poses gives one relative motion: `A_ij = ee_i_from_ee_j =
//! base_from_ee_i^-1 * base_from_ee_j` and `B_ij = cam_i_from_cam_j = camera_from_target_i *
//! camera_from_target_j^-1`; a fixed target makes `A_ij * X = X * B_ij`.
//!
//! The method ([`calibrate`]):
//! 1. a closed form over the pairs: Park-Martin (rotation by Kabsch/SVD on the log-rotations,
//!    translation by linear least squares), Tsai-Lenz (modified Rodrigues vectors) or Daniilidis
//!    (dual quaternions, SVD of the stacked 6x8 constraints). Every pair up to 447 poses (100 000
//!    pairs); beyond, each pose is paired with the `100 000 / N` poses rotating the flange most among
//!    twice as many spread over the list, a deterministic set of at most 100 000 pairs, so memory and
//!    time grow linearly with the count;
//! 2. a Levenberg-Marquardt refinement of `X` jointly with `Y = base_from_target` over all poses,
//!    starting from the closed form (and the robust mean below for `Y`): per pose the discrepancy
//!    `D_i = Y^-1 * base_from_ee_i * X * camera_from_target_i` contributes its translation (metres)
//!    and rotation vector (radians, weighted by [`HandEyeParams::rotation_weight_m`] metres per
//!    radian); each measurement enters once, unlike the pairs of the closed forms, which is what
//!    brings the error under 1 mm at 0.5 mm / 0.1 deg detector noise. The refined `X` must stay
//!    near the closed forms ([`RefinementCheck`]): its shift from the method's closed form is
//!    compared with the three closed forms' largest disagreement plus 3 sigma of the difference
//!    (the closed form's by a grouped jackknife over the final inliers and the refinement's from
//!    step 6, combined), in translation and rotation (on simulated captures the shift is 0.2-1.2 mm
//!    against limits of 2.5-5.3 mm; the refinement's sigma grows with `rotation_weight_m`, and
//!    with it the limits); beyond either limit the data hold an error the
//!    model lacks (a wrong tag size, a biased detector, noise unlike `rotation_weight_m`), the
//!    result is the closed form (with the robust mean as `Y`) and a
//!    [`Diagnosis::RefinementDisagrees`] warning says so;
//! 3. per-pose residuals: each pose implies `base_from_target_i = base_from_ee_i * X *
//!    camera_from_target_i`; its residual is the translation (mm) and rotation (deg) from their robust
//!    mean (geometric median of the translations, L1 / Weiszfeld mean of the rotations) over the
//!    inlier poses; [`HandEyeResult::base_from_target`] is the refined `Y` (the robust mean when
//!    refinement is off);
//! 4. outlier rejection, one pose at a time: a pose is an outlier when its translation residual
//!    exceeds both `outlier_factor x median` and `outlier_floor_mm`, or its rotation residual both
//!    `outlier_factor x median` and `outlier_floor_deg` (medians over the current inliers); the worst
//!    one (largest ratio to its threshold) is dropped and steps 1-3 run again, until none is left or
//!    `max_rejected_fraction` of the poses are gone (then a warning) or 3 poses would remain;
//! 5. motion diversity: the unit rotation axes of the pairs rotating more than `min_pair_angle_deg`;
//!    their scatter matrix `S = mean(k k^T)` has a middle eigenvalue `l2`, and `2 asin(sqrt(l2))` is
//!    the "axis angle" (two equally used axes `phi` apart give exactly `phi`; all axes parallel give
//!    0). Below `degenerate_axis_angle_deg` (or with fewer than 2 rotating pairs) calibration is
//!    refused (the rotation about the common axis and the translation along it are unobservable);
//!    below `min_axis_angle_deg` the result carries a warning;
//! 6. uncertainty ([`HandEyeUncertainty`]): the 1-sigma of `T_ee_camera` per axis from the
//!    refinement's Jacobian over the final inliers, and of a scale factor on the `T_camera_target`
//!    translations fitted with it (a wrong tag or board size); a warning when the translation's
//!    predicted 95 % error bound (the 0.95 quantile of the 3D error's norm) exceeds `tolerance_mm`
//!    (small rotations, or rotations about one axis) or the scale's 1-sigma exceeds
//!    `max_scale_sigma_percent` (pure rotations about the target: every view at one distance, so a
//!    size error passes into the camera's offset along its optical axis, 4.5 mm per percent at
//!    0.45 m, with no rise in the residuals). Where the scale is determined, the scale factor that
//!    fits best ([`HandEyeUncertainty::fitted_scale`]) gives a [`Diagnosis::ScaleMismatch`] warning
//!    when it differs from 1 by more than `scale_mismatch_percent` and 3 of its sigmas;
//! 7. the pose convention: Park-Martin solved again with every `T_base_ee`, every `T_camera_target`,
//!    or both inverted ([`InversionFit`]); when one field inverted fits `inverted_fit_factor` times
//!    better (median translation residual over all poses) and the median as given exceeds
//!    `outlier_floor_mm`, calibration is refused naming the field (on simulated captures the
//!    inverted files fit 30-230x worse than the right ones: 28-170 mm against 0.5-0.9 mm). Both fields
//!    inverted fit exactly as well as the right convention (the solver then returns `T_base_target`
//!    as `T_ee_camera` and the reverse); that case is refused when the camera comes out farther from
//!    the flange than the target from the robot base. For the same reason the two single inversions
//!    fit equally well on exact data (each is the other with both fields inverted), and their
//!    residuals differ only by the lever arms the noise acts on: the field named is the one whose
//!    solution puts the camera nearer the flange relative to the target's distance from the base
//!    ([`InversionFit::camera_from_flange_m`], [`InversionFit::target_from_base_m`]), the other is
//!    quoted in the message. `allow_inverted_fit` turns the refusals into
//!    [`Diagnosis::InvertedConvention`] warnings.
//!
//! Every warning is a [`HandEyeWarning`]: a [`Diagnosis`] (serialised by name) and a message saying
//! what is wrong and what capture would fix it. [`HandEyeResult`] gives the residual RMS over the
//! inliers and over all poses.
//!
//! # The poses file (`awl-handeye/1`)
//!
//! ```json
//! {"format": "awl-handeye/1",
//!  "poses": [{"T_base_ee": [[r00, r01, r02, tx], [..], [..], [0, 0, 0, 1]],
//!             "T_camera_target": [[..], [..], [..], [0, 0, 0, 1]]}, ...]}
//! ```
//! 4x4 row-major rigid matrices, metres; `T_base_ee` from the arm's forward kinematics,
//! `T_camera_target` from the tag/board detector. Read and written by [`crate::handeye::poses_file`].
//!
//! Tsai-Lenz divides by `cos(angle/2)` of `X`'s rotation: it loses accuracy as that angle nears 180
//! degrees (Park-Martin and Daniilidis do not).

pub mod capture;
pub(crate) mod capture_bound;
pub mod chain;
mod daniilidis;
mod diagnosis;
mod diversity;
mod motion;
mod park;
pub mod poses_file;
mod refine;
mod residual;
mod solve;
mod tsai;
mod uncertainty;

use nalgebra::Isometry3;
use serde::{Deserialize, Serialize};

pub use capture::{CaptureCalibration, CaptureParams, CaptureViewReport, FlipChoice, calibrate_capture};
pub use capture_bound::{BOUND_PROBABILITY, CaptureBound};
pub use diagnosis::{Diagnosis, HandEyeWarning, Inversion, InversionFit};
pub use diversity::MotionDiversity;
pub use refine::{RefineStats, RefinementCheck};
pub use residual::PoseResidual;
pub use solve::calibrate;
pub use uncertainty::HandEyeUncertainty;

/// One calibration pose: where the arm put the flange and where the camera saw the target.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HandEyePose {
    /// `T_base_ee`: the flange in the arm's base frame (forward kinematics).
    pub base_from_ee: Isometry3<f64>,
    /// `T_camera_target`: the target in the camera frame (tag / board detector).
    pub camera_from_target: Isometry3<f64>,
}

/// The closed-form solver that starts the refinement.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum HandEyeMethod {
    /// Park & Martin 1994: rotation from the log-rotations (SVD), translation by least squares.
    #[default]
    Park,
    /// Tsai & Lenz 1989: modified Rodrigues vectors, then the same translation least squares.
    Tsai,
    /// Daniilidis 1999: dual quaternions, rotation and translation at once.
    Daniilidis,
}

impl HandEyeMethod {
    /// The name used on the command line and in files.
    pub fn name(self) -> &'static str {
        match self {
            Self::Park => "park",
            Self::Tsai => "tsai",
            Self::Daniilidis => "daniilidis",
        }
    }
}

/// Settings of [`calibrate`]; every field has a documented default.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct HandEyeParams {
    /// Closed-form solver. Default Park.
    pub method: HandEyeMethod,
    /// Run the nonlinear refinement after the closed form. Default true.
    pub refine: bool,
    /// Weight of the rotation residuals in the refinement, metres per radian (1 mrad counts like
    /// 0.3 mm, the ratio of a tag detector's 0.5 mm to 0.1 deg). Default 0.3.
    pub rotation_weight_m: f64,
    /// Refinement iteration cap. Default 50.
    pub max_iterations: usize,
    /// A pose is an outlier above this many times the median residual (and the floor). Default 3.
    pub outlier_factor: f64,
    /// Translation residuals below this never make an outlier, millimetres. Default 2.
    pub outlier_floor_mm: f64,
    /// Rotation residuals below this never make an outlier, degrees. Default 0.3.
    pub outlier_floor_deg: f64,
    /// At most this fraction of the poses is rejected. Default 0.3.
    pub max_rejected_fraction: f64,
    /// Pairs rotating less than this do not count toward the motion diversity, degrees. Default 5.
    pub min_pair_angle_deg: f64,
    /// Below this axis angle (see the module docs) the result carries a warning, degrees. Default 20.
    pub min_axis_angle_deg: f64,
    /// Below this axis angle calibration is refused as degenerate, degrees. Default 0.5.
    pub degenerate_axis_angle_deg: f64,
    /// The error of `T_ee_camera`'s translation the user can accept, millimetres: warn
    /// ([`Diagnosis::TranslationUndetermined`]) when its predicted 95 % bound
    /// ([`HandEyeUncertainty::translation_bound_95_mm`], the 0.95 quantile of the 3D error's norm)
    /// exceeds it. Default 2.
    pub tolerance_mm: f64,
    /// Warn ([`Diagnosis::ScaleUndetermined`]) when the 1-sigma of a scale factor on the target
    /// translations exceeds this, percent. Default 1.
    pub max_scale_sigma_percent: f64,
    /// Warn ([`Diagnosis::ScaleMismatch`]) when the fitted scale factor on the target translations
    /// differs from 1 by more than this and by more than 3 of its sigmas, percent. Default 1.
    pub scale_mismatch_percent: f64,
    /// The residual noise the sigmas assume at least (per component), millimetres. Default 0.25.
    pub min_noise_mm: f64,
    /// Refuse when the poses fit this many times better (median translation residual) with a field
    /// inverted and their median residual as given exceeds `outlier_floor_mm`. Default 5.
    pub inverted_fit_factor: f64,
    /// Accept such poses as given, with a [`Diagnosis::InvertedConvention`] warning. Default false.
    pub allow_inverted_fit: bool,
    /// The most poses a calibration takes. The closed forms use every pose pair up to 447 poses and
    /// a bounded set of 100 000 pairs beyond (module docs), so memory and time grow linearly with the
    /// count (5 000 poses: about a second). Default 100 000.
    pub max_poses: usize,
}

impl Default for HandEyeParams {
    fn default() -> Self {
        Self {
            method: HandEyeMethod::Park,
            refine: true,
            rotation_weight_m: 0.3,
            max_iterations: 50,
            outlier_factor: 3.0,
            outlier_floor_mm: 2.0,
            outlier_floor_deg: 0.3,
            max_rejected_fraction: 0.3,
            min_pair_angle_deg: 5.0,
            min_axis_angle_deg: 20.0,
            degenerate_axis_angle_deg: 0.5,
            tolerance_mm: 2.0,
            max_scale_sigma_percent: 1.0,
            scale_mismatch_percent: 1.0,
            min_noise_mm: 0.25,
            inverted_fit_factor: 5.0,
            allow_inverted_fit: false,
            max_poses: 100_000,
        }
    }
}

/// What [`calibrate`] found.
#[derive(Debug, Clone, PartialEq)]
pub struct HandEyeResult {
    /// `T_ee_camera`: the refined solution (the closed form when refinement is off, or when the
    /// refinement left the closed forms' agreement: [`HandEyeResult::refinement_check`]).
    pub ee_from_camera: Isometry3<f64>,
    /// The method's closed-form solution on the final inlier poses (before refinement).
    pub closed_form_ee_from_camera: Isometry3<f64>,
    /// The refinement's solution on the final inlier poses, kept or not (the closed form when
    /// refinement is off).
    pub refined_ee_from_camera: Isometry3<f64>,
    /// `T_base_target`: the refined `Y` (the inliers' robust mean when refinement is off).
    pub base_from_target: Isometry3<f64>,
    /// The closed-form method used.
    pub method: HandEyeMethod,
    /// One entry per input pose (rejected ones included), in input order.
    pub residuals: Vec<PoseResidual>,
    /// Indices of the rejected poses, in rejection order.
    pub rejected: Vec<usize>,
    /// RMS translation residual over the inliers, millimetres.
    pub rms_translation_mm: f64,
    /// RMS rotation residual over the inliers, degrees.
    pub rms_rotation_deg: f64,
    /// RMS translation residual over all poses (rejected ones from the inliers' mean), millimetres.
    pub rms_all_translation_mm: f64,
    /// RMS rotation residual over all poses, degrees.
    pub rms_all_rotation_deg: f64,
    /// 1-sigma of `T_ee_camera` per axis and of the target scale, from the final inliers.
    pub uncertainty: HandEyeUncertainty,
    /// The fit of the poses with `T_base_ee`, `T_camera_target` or both inverted (the convention check).
    pub inversion_fits: Vec<InversionFit>,
    /// Diversity of the inliers' relative rotations.
    pub diversity: MotionDiversity,
    /// The final refinement's statistics (zero iterations when refinement is off).
    pub refinement: RefineStats,
    /// How far the refinement moved from the closed forms and whether it was kept (none when
    /// refinement is off).
    pub refinement_check: Option<RefinementCheck>,
    /// Non-fatal problems, each named by its [`Diagnosis`].
    pub warnings: Vec<HandEyeWarning>,
}
