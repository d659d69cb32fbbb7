//! `awl simulate` (being written).

/// Arguments of `awl simulate`.
#[derive(clap::Args)]
pub struct SimulateArgs {}

/// Runs `awl simulate`.
pub fn run(_args: &SimulateArgs) -> anyhow::Result<()> {
    anyhow::bail!("awl simulate is not built yet")
}
