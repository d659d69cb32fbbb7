//! Piercing: the workpiece located in the robot base frame from a piercing-time shot ([`locate`]),
//! targets on the model turned into tool poses there ([`plan`], [`tool`]), each with the error it
//! may have and whether the tool may go ([`predict`]), and robot programs ([`script`]); plan.json I/O in [`crate::pierce::plan_file`],
//! and what `awl send` checks of it before it sends ([`verify`]).
//!
//! Frames: `base` = the robot base (the shot's world frame); `model` = the fused model's frame (the
//! scan's world frame), where `workpiece.json` gives `T_world_tag`; tool z = the piercing direction.

pub mod locate;
pub mod plan;
pub mod plan_file;
pub mod predict;
pub mod reach;
pub mod safety;
pub mod script;
pub mod tool;
pub mod verify;

pub use locate::{HandEyePrior, LocateParams, Located, ShotHandEye, ShotRefineParams, ShotRefinement, locate};
pub use plan::{AxisChoice, MIN_SHOT_FITNESS, PierceParams, PiercePlan, PlannedTarget, plan, target_geometry};
pub use predict::{PredictParams, Prediction, Tolerance};
pub use reach::{
    PathJoints, ReachParams, ReachSetup, ReachWork, TargetReach, plan_reach, plan_reach_with, reach_target, shot_joints,
};
pub use safety::check_for_robot;
pub use script::{
    ProgramPlan, ProgramTarget, ScriptSpeeds, program_text, techman_packets, techman_packets_of, tmsct_packet,
    urscript, urscript_of,
};
pub use tool::{MAX_DEPTH_M, MAX_REACH_M, Stroke, ToolPoses, quaternion_xyzw, tm_pose, tool_poses, ur_pose};
