//! `robot-agent sim`.

/// Arguments of `robot-agent sim`.
#[derive(Debug, clap::Args)]
pub struct SimArgs {}

/// Runs `robot-agent sim`.
pub fn run(_args: SimArgs) -> anyhow::Result<()> {
    anyhow::bail!("robot-agent sim: not built yet")
}
