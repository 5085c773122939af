//! `robot-agent gnss`.

/// Arguments of `robot-agent gnss`.
#[derive(Debug, clap::Args)]
pub struct GnssArgs {}

/// Runs `robot-agent gnss`.
pub fn run(_args: GnssArgs) -> anyhow::Result<()> {
    anyhow::bail!("robot-agent gnss: not built yet")
}
