//! The `awl` command-line tool: parses arguments and hands each subcommand to its module.

mod cmd;
mod malloc;

use clap::{Parser, Subcommand};

/// awl: model a large workpiece from many depth views, then plan piercing poses on it.
#[derive(Parser)]
#[command(name = "awl", version, about, long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Calibrate the rig: `awl calibrate hand-eye` solves T_ee_camera from robot poses and target observations.
    Calibrate(cmd::calibrate::CalibrateArgs),
    /// Summarise a scan folder or a point-cloud / mesh file: views, pose sources, point counts, bounds.
    Info(cmd::info::InfoArgs),
    /// Run the whole job on a simulated scan: simulate, fuse, evaluate; prints the headline and the reports' paths.
    Demo(cmd::demo::DemoArgs),
    /// Align a model to its CAD and measure it: summary.json, errors.ply (heatmap), T_object_model.json, report.html.
    Evaluate(cmd::evaluate::EvaluateArgs),
    /// Fuse a scan folder's views into one model of the object: model.ply + report.json.
    Fuse(cmd::fuse::FuseArgs),
    /// Import a recording of the rig: `awl import rosbag BAG -o SCAN_DIR` (ROS 2 MCAP or sqlite3) writes a scan folder.
    Import(cmd::import::ImportArgs),
    /// Find the workpiece by its tag in a piercing-time shot; plan approach/pierce/retract tool poses (plan.json, URScript).
    Pierce(cmd::pierce::PierceArgs),
    /// Choose the views a shot still needs for its targets' predicted errors to meet a tolerance
    PlanViews(cmd::plan_views::PlanViewsArgs),
    /// Send a plan's robot program to a UR (primary/secondary interface) or Techman (listen node) controller, or print its bytes.
    Send(cmd::send::SendArgs),
    /// Register one cloud to another (coarse-to-fine point-to-plane ICP): writes T_target_source.
    Register(cmd::register::RegisterArgs),
    /// The reference paper's piercing trials in simulation (calibrate, scan + fuse, shots, pierce) as its Tables I-IV.
    Trial(cmd::trial::TrialArgs),
    /// Detect AprilTags in PNG / JPEG images: ids, corners, hamming, decision margin; both poses given the camera and tag size.
    Tags(cmd::tags::TagsArgs),
    /// Simulate the rig: render a scan folder (depth, color, poses with noise) plus truth.json and cad.ply.
    Simulate(cmd::simulate::SimulateArgs),
}

/// The x86-64 features this build was compiled for (`.cargo/config.toml`) that the CPU lacks:
/// running on without them would end in an illegal instruction.
fn missing_cpu_features() -> Vec<&'static str> {
    #[cfg(target_arch = "x86_64")]
    {
        let mut missing = Vec::new();
        macro_rules! need {
            ($($f:tt),*) => {$(
                if cfg!(target_feature = $f) && !std::arch::is_x86_feature_detected!($f) {
                    missing.push($f);
                }
            )*};
        }
        need!("avx", "avx2", "fma", "bmi1", "bmi2", "lzcnt", "movbe", "f16c", "sse4.2", "popcnt");
        missing
    }
    #[cfg(not(target_arch = "x86_64"))]
    Vec::new()
}

fn main() -> std::process::ExitCode {
    let missing = missing_cpu_features();
    if !missing.is_empty() {
        eprintln!(
            "error: this awl was built for x86-64-v3 CPUs and this CPU lacks {}; rebuild it for any \
             x86-64 with: RUSTFLAGS=\"-C target-cpu=x86-64\" cargo build --release -p awl-cli",
            missing.join(", ")
        );
        return std::process::ExitCode::from(2);
    }
    malloc::one_arena();
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Calibrate(args) => cmd::calibrate::run(&args),
        Command::Demo(args) => cmd::demo::run(&args),
        Command::Info(args) => cmd::info::run(&args),
        Command::Evaluate(args) => cmd::evaluate::run(&args),
        Command::Fuse(args) => cmd::fuse::run(&args),
        Command::Import(args) => cmd::import::run(&args),
        Command::Pierce(args) => cmd::pierce::run(&args),
        Command::PlanViews(args) => cmd::plan_views::run(&args),
        Command::Register(args) => cmd::register::run(&args),
        Command::Send(args) => cmd::send::run(&args),
        Command::Simulate(args) => cmd::simulate::run(&args),
        Command::Tags(args) => cmd::tags::run(&args),
        Command::Trial(args) => cmd::trial::run(&args),
    };
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => match e.downcast_ref::<cmd::common::NoGo>() {
            Some(no_go) => {
                eprintln!("no-go: {no_go}");
                std::process::ExitCode::from(cmd::common::NoGo::EXIT_CODE)
            }
            None => {
                eprintln!("error: {e:#}");
                std::process::ExitCode::FAILURE
            }
        },
    }
}
