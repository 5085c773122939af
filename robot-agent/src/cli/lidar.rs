//! `robot-agent lidar`: Velodyne VLP-16 packets (pcap capture, ROS 2 bag, live UDP) into PCD scans.
//!
//! Every scan written prints one JSON line on stdout (`index`, `points`, `packets`, `complete`,
//! `coverage_deg`, `stamp_s`, `malformed` = packets rejected since the previous scan, `path`),
//! then one `summary` line with the packet counts by reason and the decoding rate. PCD files hold
//! `x y z intensity ring t` in the sensor frame (x forward, y left, z up; `ring` = laser id, `t`
//! seconds since the scan's first return); see `sensing::velodyne` for the conventions.

use anyhow::{bail, Context};
use sensing::velodyne::source::PacketFile;
use sensing::velodyne::udp::UdpScanSource;
use sensing::velodyne::{
    AzimuthInterpolation, DecodeStats, LidarScan, ScanAssembler, VelodyneConfig, DATA_PORT,
};
use std::net::{IpAddr, SocketAddr};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// Arguments of `robot-agent lidar`.
#[derive(Debug, clap::Args)]
pub struct LidarArgs {
    #[command(subcommand)]
    command: LidarCommand,
}

#[derive(Debug, clap::Subcommand)]
enum LidarCommand {
    /// Decode a pcap capture or a ROS 2 bag (.db3) into one PCD per scan.
    Decode(DecodeArgs),
    /// Receive packets on a UDP socket and decode them into scans.
    Listen(ListenArgs),
    /// Publish a ROS 2 bag's VelodyneScan messages on a ROS 2 topic over Zenoh, as a VLP-16
    /// driver would (to feed `robot-agent run --lidar-msg VelodyneScan`); one summary line.
    Play(PlayArgs),
}

/// Decoder settings shared by both subcommands.
#[derive(Debug, clap::Args)]
struct DecoderOpts {
    /// Azimuth where scans are cut, degrees, or `start` for wherever the stream begins.
    #[arg(long, default_value = "0")]
    cut_angle: String,
    /// Drop returns at or below this distance, metres.
    #[arg(long, default_value_t = VelodyneConfig::default().min_range_m)]
    min_range: f32,
    /// Drop returns at or beyond this distance, metres.
    #[arg(long, default_value_t = VelodyneConfig::default().max_range_m)]
    max_range: f32,
    /// Reproduce Autoware nebula's decoding exactly (its azimuth arithmetic, 300 m max range,
    /// azimuths 0..359 deg), e.g. to compare with its PCDs. Overrides --max-range.
    #[arg(long)]
    nebula_compat: bool,
    /// Accept packets whose product byte is not 0x22 (early VLP-16 firmware writes 0x21).
    #[arg(long)]
    any_product: bool,
}

impl DecoderOpts {
    fn config(&self) -> anyhow::Result<VelodyneConfig> {
        let mut c = if self.nebula_compat {
            VelodyneConfig::nebula_reference()
        } else {
            VelodyneConfig {
                max_range_m: self.max_range,
                ..VelodyneConfig::default()
            }
        };
        c.min_range_m = self.min_range;
        c.require_vlp16_product = !self.any_product;
        c.cut_angle_deg = match self.cut_angle.as_str() {
            "start" => None,
            s => Some(
                s.parse::<f32>()
                    .with_context(|| format!("--cut-angle {s:?}: degrees or `start`"))?,
            ),
        };
        if self.nebula_compat {
            c.interpolation = AzimuthInterpolation::NebulaCompat;
        }
        Ok(c)
    }
}

#[derive(Debug, clap::Args)]
struct DecodeArgs {
    /// Input: a classic pcap capture or a rosbag2 SQLite file (.db3).
    file: PathBuf,
    /// Output PCD: scans go to OUT_000.pcd, OUT_001.pcd, ... (or OUT itself with --scan-index).
    #[arg(long)]
    out: PathBuf,
    /// Write only this scan (0-based, counting every scan of the stream, partial ones too).
    #[arg(long)]
    scan_index: Option<usize>,
    /// Write only full rotations (skip the partial scans at the ends of the stream).
    #[arg(long)]
    complete_only: bool,
    /// UDP destination port of data packets in a pcap.
    #[arg(long, default_value_t = DATA_PORT)]
    port: u16,
    /// Bag topic (default: the first velodyne_msgs/msg/VelodyneScan topic).
    #[arg(long)]
    topic: Option<String>,
    #[command(flatten)]
    decoder: DecoderOpts,
}

#[derive(Debug, clap::Args)]
struct ListenArgs {
    /// UDP port to listen on.
    #[arg(long, default_value_t = DATA_PORT)]
    port: u16,
    /// Address to bind (0.0.0.0 receives the sensor's broadcast on every interface).
    #[arg(long, default_value = "0.0.0.0")]
    bind: IpAddr,
    /// Stop after this many scans (default: run until no packet arrives for --idle-timeout-s).
    #[arg(long)]
    scans: Option<usize>,
    /// Write scans to DIR/NNN.pcd.
    #[arg(long)]
    out: Option<PathBuf>,
    /// Give up when no scan completes for this long, seconds.
    #[arg(long, default_value_t = 10.0)]
    idle_timeout_s: f64,
    #[command(flatten)]
    decoder: DecoderOpts,
}

#[derive(Debug, clap::Args)]
struct PlayArgs {
    /// The bag: a rosbag2 SQLite file (.db3), or its folder.
    bag: PathBuf,
    /// Bag topic (default: the first velodyne_msgs/msg/VelodyneScan topic).
    #[arg(long)]
    topic: Option<String>,
    /// Topic to publish on (default: the bag topic).
    #[arg(long = "as", value_name = "TOPIC")]
    publish_as: Option<String>,
    /// ROS 2 key form: `bridge` (zenoh-bridge-ros2dds) or `rmw` (rmw_zenoh).
    #[arg(long, default_value = "bridge", value_name = "FORM")]
    ros2_keys: String,
    /// ROS 2 namespace.
    #[arg(long, default_value = "", value_name = "NS")]
    ros2_namespace: String,
    /// ROS_DOMAIN_ID (rmw form).
    #[arg(long, default_value_t = 0, value_name = "ID")]
    ros2_domain_id: u32,
    /// Zenoh endpoint to listen on, as a bridge does (e.g. tcp/127.0.0.1:7450).
    #[arg(long, value_name = "ENDPOINT")]
    listen: Vec<String>,
    /// Zenoh endpoint to connect to.
    #[arg(long, value_name = "ENDPOINT")]
    connect: Vec<String>,
    /// Speed factor (2: twice as fast as recorded).
    #[arg(long, default_value_t = 1.0)]
    rate: f64,
    /// Wait this long for a subscriber before the first message (0: start at once), seconds.
    #[arg(long, default_value_t = 30.0, value_name = "S")]
    wait_subscriber_s: f64,
    /// Move every stamp so the first message is stamped now (to mix with live sensors).
    #[arg(long)]
    restamp: bool,
}

/// Runs `robot-agent lidar`.
pub fn run(args: LidarArgs) -> anyhow::Result<()> {
    match args.command {
        LidarCommand::Decode(a) => decode(a),
        LidarCommand::Listen(a) => listen(a),
        LidarCommand::Play(a) => play(a),
    }
}

fn play(a: PlayArgs) -> anyhow::Result<()> {
    let form = a
        .ros2_keys
        .parse()
        .map_err(|e: String| anyhow::anyhow!("--ros2-keys: {e}"))?;
    let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    super::run::stop_on_signals(stop.clone())?;
    let summary = crate::run::bag_play::play(
        &crate::run::bag_play::PlayOptions {
            bag: a.bag,
            topic: a.topic,
            publish_as: a.publish_as,
            graph: io::ros2::Ros2Graph {
                form,
                domain_id: a.ros2_domain_id,
                namespace: a.ros2_namespace,
            },
            zenoh: crate::bus::ZenohSettings {
                listen: a.listen,
                connect: a.connect,
                ..Default::default()
            },
            rate: a.rate,
            wait_subscriber_s: a.wait_subscriber_s,
            restamp: a.restamp,
        },
        &stop,
    )?;
    println!("{summary}");
    Ok(())
}

/// Numbered output path: `dir/name.pcd` -> `dir/name_007.pcd`.
fn numbered(out: &Path, index: usize) -> PathBuf {
    let stem = out
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "scan".into());
    out.with_file_name(format!("{stem}_{index:03}.pcd"))
}

fn scan_line(s: &LidarScan, malformed: u64, path: Option<&Path>) -> String {
    serde_json::json!({
        "index": s.index,
        "points": s.returns.len(),
        "packets": s.packets,
        "complete": s.complete,
        "coverage_deg": (s.coverage_deg * 100.0).round() / 100.0,
        "stamp_s": s.stamp_s,
        "malformed": malformed,
        "path": path.map(|p| p.display().to_string()),
    })
    .to_string()
}

/// Writes the scans asked for, one JSON line each; tracks malformed packets between scans.
struct Writer<'a> {
    out: &'a Path,
    scan_index: Option<usize>,
    complete_only: bool,
    written: usize,
    malformed_seen: u64,
}

impl Writer<'_> {
    fn take(&mut self, s: &LidarScan, stats: &DecodeStats) -> anyhow::Result<()> {
        let malformed = stats.malformed() - self.malformed_seen;
        self.malformed_seen = stats.malformed();
        let wanted = match self.scan_index {
            Some(k) => s.index == k,
            None => !self.complete_only || s.complete,
        };
        if !wanted {
            return Ok(());
        }
        let path = if self.scan_index.is_some() {
            self.out.to_path_buf()
        } else {
            numbered(self.out, s.index)
        };
        sensing::pcd::write_pcd(&path, &s.to_scan().points)
            .with_context(|| format!("writing {}", path.display()))?;
        self.written += 1;
        println!("{}", scan_line(s, malformed, Some(&path)));
        Ok(())
    }
}

fn decode(a: DecodeArgs) -> anyhow::Result<()> {
    let config = a.decoder.config()?;
    let mut file = PacketFile::open(&a.file, Some(a.port), a.topic.as_deref())
        .with_context(|| format!("opening {}", a.file.display()))?;
    if let Some(dir) = a.out.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    let mut asm = ScanAssembler::new(config);
    let mut w = Writer {
        out: &a.out,
        scan_index: a.scan_index,
        complete_only: a.complete_only,
        written: 0,
        malformed_seen: 0,
    };
    let mut scans = 0usize;
    let started = Instant::now();
    let mut decode_s = 0.0;
    while let Some(p) = file.next_packet()? {
        let t0 = Instant::now();
        let done = asm.push_packet(&p.data, p.stamp_s);
        decode_s += t0.elapsed().as_secs_f64();
        for s in done {
            scans += 1;
            w.take(&s, asm.stats())?;
        }
        if a.scan_index.is_some_and(|k| scans > k) {
            break; // the requested scan is written
        }
    }
    if a.scan_index.is_none_or(|k| scans <= k) {
        if let Some(s) = asm.finish() {
            scans += 1;
            w.take(&s, asm.stats())?;
        }
    }
    let stats = asm.stats();
    let total_packets = stats.packets_ok + stats.malformed();
    println!(
        "{}",
        serde_json::json!({
            "summary": {
                "file": a.file.display().to_string(),
                "scans": scans,
                "written": w.written,
                "packets": stats,
                "file_stats": file.stats(),
                "elapsed_s": started.elapsed().as_secs_f64(),
                "decode_packets_per_s": if decode_s > 0.0 { (total_packets as f64 / decode_s).round() } else { 0.0 },
            }
        })
    );
    if let Some(e) = file.last_cdr_error() {
        eprintln!("robot-agent lidar: skipped bag messages with corrupt CDR (last: {e})");
    }
    if stats.packets_ok == 0 && stats.unknown_product > 0 && !a.decoder.any_product {
        bail!("no packet had the VLP-16 product id 0x22; early VLP-16 firmware writes 0x21: try --any-product");
    }
    if let Some(k) = a.scan_index {
        if w.written == 0 {
            bail!(
                "scan {k} not found: the stream has {scans} scans (0..{})",
                scans.saturating_sub(1)
            );
        }
    } else if w.written == 0 {
        bail!("no scan decoded from {}", a.file.display());
    }
    Ok(())
}

fn listen(a: ListenArgs) -> anyhow::Result<()> {
    let config = a.decoder.config()?;
    let addr = SocketAddr::new(a.bind, a.port);
    let mut src = UdpScanSource::bind(addr, config).with_context(|| format!("binding {addr}"))?;
    eprintln!("robot-agent lidar: listening on {}", src.local_addr()?);
    if let Some(dir) = &a.out {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    let idle = Duration::from_secs_f64(a.idle_timeout_s.max(0.001));
    let mut got = 0usize;
    let mut malformed_seen = 0;
    while a.scans.is_none_or(|n| got < n) {
        let Some(s) = src.next_scan(idle)? else {
            eprintln!(
                "robot-agent lidar: no scan for {:.1} s, stopping",
                a.idle_timeout_s
            );
            break;
        };
        got += 1;
        let path = a
            .out
            .as_ref()
            .map(|d| d.join(format!("{:03}.pcd", s.index)));
        if let Some(p) = &path {
            sensing::pcd::write_pcd(p, &s.to_scan().points)
                .with_context(|| format!("writing {}", p.display()))?;
        }
        let m = src.stats().malformed();
        println!("{}", scan_line(&s, m - malformed_seen, path.as_deref()));
        malformed_seen = m;
    }
    println!(
        "{}",
        serde_json::json!({ "summary": { "scans": got, "datagrams": src.datagrams, "packets": src.stats() } })
    );
    if a.scans.is_some_and(|n| got < n) {
        bail!("received {got} of {} scans", a.scans.unwrap_or(0));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn numbered_names() {
        assert_eq!(
            numbered(Path::new("out/scan.pcd"), 7),
            Path::new("out/scan_007.pcd")
        );
        assert_eq!(numbered(Path::new("x"), 12), Path::new("x_012.pcd"));
    }

    fn opts(cut: &str, nebula: bool) -> DecoderOpts {
        DecoderOpts {
            cut_angle: cut.into(),
            min_range: 0.3,
            max_range: 130.0,
            nebula_compat: nebula,
            any_product: false,
        }
    }

    #[test]
    fn cut_angle_option() {
        assert_eq!(opts("start", false).config().unwrap().cut_angle_deg, None);
        assert_eq!(
            opts("90", false).config().unwrap().cut_angle_deg,
            Some(90.0)
        );
        assert!(opts("north", false).config().is_err());
        assert_eq!(
            opts("0", true).config().unwrap().interpolation,
            AzimuthInterpolation::NebulaCompat
        );
    }

    #[test]
    fn decodes_the_reference_scan_of_the_bag() {
        let data = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data/lidar/vlp16");
        if !data.is_dir() {
            println!("skipping decodes_the_reference_scan_of_the_bag: ../shared/data is absent");
            return;
        }
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("ref.pcd");
        decode(DecodeArgs {
            file: data.join("packets_1673400471837873222.db3"),
            out: out.clone(),
            scan_index: Some(3),
            complete_only: false,
            port: DATA_PORT,
            topic: None,
            decoder: opts("0", true),
        })
        .unwrap();
        let ours = sensing::pcd::read_pcd(&out).unwrap();
        let reference =
            sensing::pcd::read_pcd(data.join("decoded_1673400472138016708.pcd")).unwrap();
        assert_eq!(ours.len(), reference.len());
        let max_err = ours
            .iter()
            .zip(&reference)
            .map(|(a, b)| ((a.x - b.x).powi(2) + (a.y - b.y).powi(2) + (a.z - b.z).powi(2)).sqrt())
            .fold(0.0f32, f32::max);
        assert!(max_err < 0.01, "{max_err}");
        // A scan index beyond the stream is an error, not an empty success.
        let missing = decode(DecodeArgs {
            file: data.join("packets_1673400471837873222.db3"),
            out: dir.path().join("none.pcd"),
            scan_index: Some(99),
            complete_only: false,
            port: DATA_PORT,
            topic: None,
            decoder: opts("0", false),
        });
        assert!(missing.is_err());
    }
}
