//! The piercing plan: targets placed on the model, the model located in the base frame from a
//! shot, and for each target the point, the piercing axis and the tool poses in the base frame.

use nalgebra::{Isometry3, Point3, Vector3};
use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::pierce::locate::{LocateParams, Located, locate};
use crate::pierce::predict::{PredictParams, Prediction, TargetGeometry, Tolerance, predict};
use crate::pierce::tool::{Stroke, ToolPoses, tool_poses};
use crate::scan::{Scan, TagSpec};
use crate::workpiece::{SurfaceModel, SurfaceTarget, TargetParams, TargetSpec};

/// Which direction the tool pierces along.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum AxisChoice {
    /// Into the model's surface at the target (right for curved surfaces). The default.
    #[default]
    Normal,
    /// Along the tag's z axis, into the workpiece (the reference system's choice).
    Tag,
}

impl AxisChoice {
    /// The name used on the command line and in plan.json.
    pub fn name(self) -> &'static str {
        match self {
            Self::Normal => "normal",
            Self::Tag => "tag",
        }
    }
}

/// Parameters of [`plan`].
#[derive(Debug, Clone, PartialEq)]
pub struct PierceParams {
    /// Target placement on the model.
    pub targets: TargetParams,
    /// Tag detection in the shot and the shot-depth refinement.
    pub locate: LocateParams,
    /// The piercing direction.
    pub axis: AxisChoice,
    /// Distances along the axis.
    pub stroke: Stroke,
    /// The hand-eye to start from (`None`: the shot's recorded `T_ee_camera` with the default
    /// prior sigma).
    pub hand_eye: Option<crate::pierce::locate::HandEyePrior>,
    /// The model's share of each target's predicted error.
    pub predict: PredictParams,
    /// The most a target may be off for the tool to go.
    pub tolerance: Tolerance,
    /// How far apart the fuse found parts of the model (workpiece.json
    /// `hand_eye.rejected_disagreement_mm`), metres; 0: none. Added to each target's prediction.
    pub model_disagreement_m: f64,
    /// The least share of the shot's points (near the model placed by the tag) that must fit the
    /// model for any target to go ([`ShotRefinement::fitness`](crate::pierce::ShotRefinement)).
    /// Default [`MIN_SHOT_FITNESS`].
    pub min_shot_fitness: f64,
}

/// The default [`PierceParams::min_shot_fitness`]: shots fit their own model at 0.73-0.98 (both
/// simulators, 2 to 18 views, fused and CAD-sampled models), another part's model at 0.13-0.30 (and
/// 0.56 once, where the registration then moved the tag 146 mm, beyond its gate): BENCHMARKS.md,
/// "Shot fitness".
pub const MIN_SHOT_FITNESS: f64 = 0.5;

impl Default for PierceParams {
    fn default() -> Self {
        Self {
            targets: TargetParams::default(),
            locate: LocateParams::default(),
            axis: AxisChoice::default(),
            stroke: Stroke::default(),
            hand_eye: None,
            predict: PredictParams::default(),
            tolerance: Tolerance::default(),
            model_disagreement_m: 0.0,
            min_shot_fitness: MIN_SHOT_FITNESS,
        }
    }
}

/// Why no target may go on this location (`None`: it may): the shot's depth, registered onto the
/// model, fits too little of it, or its registration failed its gates (the tag alone is then all
/// that places the model, and the depth disagrees with it).
fn location_refusal(located: &Located, min_fitness: f64) -> Option<String> {
    let r = located.refinement.as_ref()?;
    if !(r.fitness >= min_fitness) {
        return Some(format!(
            "the shot fits the model poorly: {:.0} % of its {} points near the model lie on it (at least {:.0} % \
             needed): the model may not be this workpiece's (check workpiece.json's model), or the workpiece moved \
             or deformed; take the shot again, or fuse the workpiece again",
            r.fitness * 1e2,
            r.points,
            min_fitness * 1e2
        ));
    }
    (!r.applied).then(|| {
        format!(
            "the shot's depth does not confirm the tag's location ({}): take the shot again with the workpiece's \
             surface around the targets in view",
            r.note
        )
    })
}

/// What [`predict`] needs of a target placed on the model, piercing along `axis_base`.
pub fn target_geometry(surface: &SurfaceTarget, axis_base: &Vector3<f64>, params: &PierceParams) -> TargetGeometry {
    TargetGeometry {
        p_model: surface.point,
        normal_model: surface.normal,
        axis_base: *axis_base,
        face_centre: surface.corners.is_some(),
        normal_covariance_model: match params.axis {
            AxisChoice::Normal => surface.normal_covariance,
            AxisChoice::Tag => nalgebra::Matrix3::identity() * params.predict.axis_sigma_rad.powi(2),
        },
        model_disagreement_m: params.model_disagreement_m,
    }
}

/// One target of the plan.
#[derive(Debug, Clone, PartialEq)]
pub struct PlannedTarget {
    /// The target on the model (model frame).
    pub surface: SurfaceTarget,
    /// The surface point, base frame.
    pub p_base: Point3<f64>,
    /// The outward surface normal, base frame.
    pub normal_base: Vector3<f64>,
    /// The piercing direction (unit, into the surface), base frame.
    pub axis_base: Vector3<f64>,
    /// The tool poses, base frame.
    pub poses: ToolPoses,
    /// How far off the point and the axis may be.
    pub prediction: Prediction,
    /// Why the predicted error exceeds the tolerance (`None`: it does not).
    pub refusal: Option<String>,
    /// Whether the arm reaches it ([`crate::pierce::reach::plan_reach`]); `None`: not checked.
    pub reach: Option<crate::pierce::reach::TargetReach>,
}

impl PlannedTarget {
    /// Why the tool must not go to this target: its predicted error exceeds the tolerance, or the
    /// arm does not reach it (`None`: it may go). No-go targets are left out of the programs.
    pub fn no_go_reason(&self) -> Option<String> {
        let why: Vec<String> = self.refusal.iter().cloned().chain(self.reach_refusal()).collect();
        (!why.is_empty()).then(|| why.join("; "))
    }

    /// Whether the tool may go to this target.
    pub fn go(&self) -> bool {
        self.no_go_reason().is_none()
    }
}

/// A piercing plan.
#[derive(Debug, Clone, PartialEq)]
pub struct PiercePlan {
    /// Where the workpiece is (and how it was found).
    pub located: Located,
    /// The model's tag pose used (`T_world_tag`, model frame).
    pub world_from_tag: Isometry3<f64>,
    /// The axis choice.
    pub axis: AxisChoice,
    /// The stroke.
    pub stroke: Stroke,
    /// The targets, in the order asked.
    pub targets: Vec<PlannedTarget>,
    /// Things the user should know (from locating and placing).
    pub warnings: Vec<String>,
    /// The tolerance the targets were judged by.
    pub tolerance: Tolerance,
    /// The probability of the predicted bounds.
    pub confidence: f64,
    /// The robot the targets' reach was checked for; `None`: not checked.
    pub reach: Option<crate::pierce::reach::ReachSetup>,
}

/// Places `specs` on the model `surface` (failing before any image is read when one is off the
/// model), locates the model in the shot's base frame and plans the tool poses.
///
/// # Errors
/// [`Error::Invalid`] for no target, a target off the model, or any error of [`locate`].
pub fn plan(
    surface: &SurfaceModel,
    tag: &TagSpec,
    world_from_tag: &Isometry3<f64>,
    shot: &Scan,
    specs: &[TargetSpec],
    params: &PierceParams,
) -> Result<PiercePlan> {
    if specs.is_empty() {
        return Err(Error::invalid("targets", "no target given"));
    }
    params.stroke.validate()?;
    params.predict.validate()?;
    params.tolerance.validate()?;
    if !(0.0..=1.0).contains(&params.model_disagreement_m) {
        return Err(Error::invalid(
            "hand_eye.rejected_disagreement_mm",
            format!("{} mm is not between 0 and 1000 mm", params.model_disagreement_m * 1e3),
        ));
    }
    let placed: Vec<SurfaceTarget> =
        specs.iter().map(|s| surface.place(s, &params.targets, Some(world_from_tag))).collect::<Result<_>>()?;
    if !(0.0..=1.0).contains(&params.min_shot_fitness) {
        return Err(Error::invalid(
            "min_shot_fitness",
            format!("{} is not a share between 0 and 1", params.min_shot_fitness),
        ));
    }
    let located = locate(shot, tag, world_from_tag, surface, &params.locate, params.hand_eye.as_ref())?;
    let mut warnings = located.warnings.clone();
    let no_location = location_refusal(&located, params.min_shot_fitness);
    if let Some(why) = &no_location {
        warnings.push(format!("every target is no-go: {why}"));
    }
    if params.model_disagreement_m > 0.0 {
        warnings.push(format!(
            "the fuse found parts of the model {:.1} mm apart (workpiece.json hand_eye.rejected_disagreement_mm: \
             views of one base stop registered apart from where the arm put them): every target's bound includes \
             it; re-scan for a model to pierce by",
            params.model_disagreement_m * 1e3
        ));
    }
    let base_from_model = located.base_from_model;
    let tag_axis = -((base_from_model * world_from_tag).rotation * Vector3::z());
    let targets = placed
        .into_iter()
        .map(|surface| {
            let p_base = base_from_model * surface.point;
            let normal_base = base_from_model.rotation * surface.normal;
            let axis_base = match params.axis {
                AxisChoice::Normal => -normal_base,
                AxisChoice::Tag => tag_axis,
            };
            if let Some(a) =
                surface.angle_to_tag_z_rad.filter(|a| params.axis == AxisChoice::Tag && *a > 10f64.to_radians())
            {
                warnings.push(format!(
                    "target {}: the tag's z axis is {:.1} deg from the surface normal: the tool will not pierce square",
                    surface.spec,
                    a.to_degrees()
                ));
            }
            let poses = tool_poses(&p_base, &axis_base, &params.stroke)?;
            let geometry = target_geometry(&surface, &axis_base, params);
            let prediction = predict(&base_from_model, &located.base_from_model_covariance, &geometry, &params.predict);
            let refusal: Vec<String> =
                no_location.iter().cloned().chain(params.tolerance.refusal(&prediction)).collect();
            let refusal = (!refusal.is_empty()).then(|| refusal.join("; "));
            Ok(PlannedTarget { surface, p_base, normal_base, axis_base, poses, prediction, refusal, reach: None })
        })
        .collect::<Result<Vec<_>>>()?;
    Ok(PiercePlan {
        located,
        world_from_tag: *world_from_tag,
        axis: params.axis,
        stroke: params.stroke,
        targets,
        warnings,
        tolerance: params.tolerance,
        confidence: params.predict.confidence,
        reach: None,
    })
}
