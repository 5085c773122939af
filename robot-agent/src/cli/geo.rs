//! `robot-agent geo`.

/// Arguments of `robot-agent geo`.
#[derive(Debug, clap::Args)]
pub struct GeoArgs {}

/// Runs `robot-agent geo`.
pub fn run(_args: GeoArgs) -> anyhow::Result<()> {
    anyhow::bail!("robot-agent geo: not built yet")
}
