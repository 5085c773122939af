//! `robot-agent lidar`.

/// Arguments of `robot-agent lidar`.
#[derive(Debug, clap::Args)]
pub struct LidarArgs {}

/// Runs `robot-agent lidar`.
pub fn run(_args: LidarArgs) -> anyhow::Result<()> {
    anyhow::bail!("robot-agent lidar: not built yet")
}
