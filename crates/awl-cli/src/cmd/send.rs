//! `awl send plan.json --ur HOST | --techman HOST [--dry-run]`: send a plan's robot program to the
//! controller (UR primary / secondary client interface, Techman listen node), or print its bytes;
//! nothing is sent unless the plan verifies ([`awl::pierce::verify`]) and every line is one of awl's
//! statements ([`awl::robot::statements`]).

use std::io::Write;
use std::path::PathBuf;
use std::time::Duration;

use awl::pierce::verify::read_plan_to_send;
use awl::robot::{TECHMAN_PORT, UR_SECONDARY_PORT, statements, techman, ur};

/// Arguments of `awl send`.
#[derive(clap::Args)]
#[command(group(clap::ArgGroup::new("controller").required(true).args(["ur", "techman"])))]
pub struct SendArgs {
    /// plan.json written by `awl pierce` (its `programs` block is what is sent).
    pub plan: PathBuf,
    /// Send the URScript program to this UR controller (port 30002, the secondary client interface; 30001 with --port).
    #[arg(long, value_name = "HOST")]
    pub ur: Option<String>,
    /// Send the listen-node packets to this Techman controller (port 5890), each after the previous one's OK.
    #[arg(long, value_name = "HOST")]
    pub techman: Option<String>,
    /// The controller's port (default: 30002 for --ur, 5890 for --techman).
    #[arg(long)]
    pub port: Option<u16>,
    /// Print exactly the bytes that would be sent, and send nothing.
    #[arg(long)]
    pub dry_run: bool,
    /// Send even when the plan has targets that are not reachable or no-go (they are not in the programs).
    #[arg(long)]
    pub allow_no_go: bool,
    /// Seconds to wait for the connection and for each answer.
    #[arg(long, default_value_t = 5.0)]
    pub timeout_s: f64,
}

/// Runs `awl send`.
pub fn run(args: &SendArgs) -> anyhow::Result<()> {
    anyhow::ensure!(
        args.timeout_s.is_finite() && args.timeout_s > 0.0 && args.timeout_s <= 600.0,
        "--timeout-s must be within (0, 600] seconds, got {}",
        args.timeout_s
    );
    let timeout = Duration::from_secs_f64(args.timeout_s);
    let plan = read_plan_to_send(&args.plan)?;
    if !plan.refused.is_empty() && !args.allow_no_go {
        let list: Vec<String> = plan.refused.iter().map(|(i, t, why)| format!("target {i} ({t}): {why}")).collect();
        anyhow::bail!(
            "{}: {} target(s) must not be run, nothing sent: {} (they are left out of the programs; --allow-no-go sends \
             the rest)",
            args.plan.display(),
            list.len(),
            list.join("; ")
        );
    }
    let (bytes, host, port) = match (&args.ur, &args.techman) {
        (Some(host), _) => (plan.urscript.as_str(), host, args.port.unwrap_or(UR_SECONDARY_PORT)),
        (None, Some(host)) => (plan.techman.as_str(), host, args.port.unwrap_or(TECHMAN_PORT)),
        (None, None) => anyhow::bail!("give --ur HOST or --techman HOST"),
    };
    // the programs were regenerated from the plan's poses and joints and compared (read_plan_to_send);
    // each line is also one of awl's statements, parsed on its own
    ur::check_program(&plan.urscript)?;
    statements::check_urscript_statements(&plan.urscript)?;
    statements::check_techman_statements(&techman::split_packets(&plan.techman)?)?;
    if args.dry_run {
        let mut out = std::io::stdout().lock();
        out.write_all(bytes.as_bytes())?;
        out.flush()?;
        return Ok(());
    }
    if args.ur.is_some() {
        let r = ur::send_program(host, port, bytes, timeout)?;
        println!(
            "sent {} bytes of URScript to {host}:{port}; the controller answered with state (message type {}, {} bytes)",
            r.sent, r.message_type, r.message_length
        );
    } else {
        let r = techman::send_packets(host, port, bytes, timeout)?;
        if let Some(m) = &r.listen_node {
            println!("the listen node at {host}:{port} said `{m}` on entering it");
        }
        println!("sent {} listen-node packets to {host}:{port}, each acknowledged OK", r.acknowledged.len());
        for (id, lines) in &r.warnings {
            println!("warning: the listen node took packet id {id} with warnings on its script lines {lines}");
        }
    }
    Ok(())
}
