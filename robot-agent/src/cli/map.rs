//! `robot-agent map`.

/// Arguments of `robot-agent map`.
#[derive(Debug, clap::Args)]
pub struct MapArgs {}

/// Runs `robot-agent map`.
pub fn run(_args: MapArgs) -> anyhow::Result<()> {
    anyhow::bail!("robot-agent map: not built yet")
}
