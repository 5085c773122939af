//! `robot-agent slam`.

/// Arguments of `robot-agent slam`.
#[derive(Debug, clap::Args)]
pub struct SlamArgs {}

/// Runs `robot-agent slam`.
pub fn run(_args: SlamArgs) -> anyhow::Result<()> {
    anyhow::bail!("robot-agent slam: not built yet")
}
