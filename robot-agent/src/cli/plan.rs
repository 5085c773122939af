//! `robot-agent plan`.

/// Arguments of `robot-agent plan`.
#[derive(Debug, clap::Args)]
pub struct PlanArgs {}

/// Runs `robot-agent plan`.
pub fn run(_args: PlanArgs) -> anyhow::Result<()> {
    anyhow::bail!("robot-agent plan: not built yet")
}
