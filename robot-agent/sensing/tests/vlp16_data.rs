//! Decoding the real VLP-16 recordings in `../shared/data/lidar/vlp16/`.

use sensing::pcd::read_pcd_full;
use sensing::velodyne::rosbag::{decode_velodyne_scan, BagReader, CdrError};
use sensing::velodyne::source::{decode_file, PacketFile};
use sensing::velodyne::udp::UdpScanSource;
use sensing::velodyne::{
    ring_by_elevation, AzimuthInterpolation, LidarScan, ScanAssembler, VelodyneConfig,
    VelodyneReturn, LASER_ELEVATION_DEG,
};
use std::path::PathBuf;
use std::time::Duration;

fn data_dir(test: &str) -> Option<PathBuf> {
    common::shared_data::locate(env!("CARGO_MANIFEST_DIR"), "lidar/vlp16", test)
}

fn bag_path(d: &std::path::Path) -> PathBuf {
    d.join("packets_1673400471837873222.db3")
}

/// Reference points: xyz, intensity, return_type, channel (elevation rank), azimuth, distance.
struct RefPoint {
    xyz: [f32; 3],
    intensity: f32,
    return_type: u8,
    channel: u16,
    azimuth_rad: f32,
    distance_m: f32,
}

fn reference(d: &std::path::Path) -> Vec<RefPoint> {
    let c = read_pcd_full(d.join("decoded_1673400472138016708.pcd")).unwrap();
    let col = |n: &str| c.field_names.iter().position(|f| f == n).unwrap();
    let (rt, ch, az, di) = (
        col("return_type"),
        col("channel"),
        col("azimuth"),
        col("distance"),
    );
    c.points
        .iter()
        .zip(&c.values)
        .map(|(p, v)| RefPoint {
            xyz: [p.x, p.y, p.z],
            intensity: p.intensity,
            return_type: v[rt] as u8,
            channel: v[ch] as u16,
            azimuth_rad: v[az] as f32,
            distance_m: v[di] as f32,
        })
        .collect()
}

fn max_error_m(scan: &LidarScan, r: &[RefPoint]) -> f64 {
    scan.returns
        .iter()
        .zip(r)
        .map(|(a, b)| {
            let p = a.point;
            (((p.x - b.xyz[0]) as f64).powi(2)
                + ((p.y - b.xyz[1]) as f64).powi(2)
                + ((p.z - b.xyz[2]) as f64).powi(2))
            .sqrt()
        })
        .fold(0.0, f64::max)
}

#[test]
fn bag_reproduces_the_reference_decoding() {
    let Some(d) = data_dir("bag_reproduces_the_reference_decoding") else {
        return;
    };
    let r = reference(&d);
    assert_eq!(r.len(), 14_831);
    let (scans, stats, fstats) =
        decode_file(bag_path(&d), VelodyneConfig::nebula_reference()).unwrap();
    assert_eq!((stats.packets_ok, stats.malformed()), (603, 0));
    assert_eq!((fstats.bag_messages, fstats.bad_cdr_messages), (4, 0));
    for s in &scans {
        println!(
            "scan {}: {} points, {} packets, coverage {:.2} deg, complete {}",
            s.index,
            s.returns.len(),
            s.packets,
            s.coverage_deg,
            s.complete
        );
    }
    // The scan matching the reference: same count, and every point within 1 cm.
    let matching: Vec<usize> = scans
        .iter()
        .filter(|s| s.returns.len() == r.len() && max_error_m(s, &r) < 0.01)
        .map(|s| s.index)
        .collect();
    assert_eq!(
        matching,
        [3],
        "the rotation completed in the bag's 4th message"
    );
    let s = &scans[3];
    let err = max_error_m(s, &r);
    println!(
        "reference scan 3: {} points, max position error {:.6} m",
        s.returns.len(),
        err
    );
    assert!(err < 0.002, "{err}");
    for (a, b) in s.returns.iter().zip(&r) {
        assert_eq!(ring_by_elevation(a.point.ring), b.channel);
        assert_eq!(a.point.intensity, b.intensity);
        assert_eq!(a.return_type.nebula_code(), b.return_type);
        assert!((a.distance_m - b.distance_m).abs() < 1e-5);
        assert!(
            (a.azimuth_rad - b.azimuth_rad).abs() < 2e-4,
            "{} {}",
            a.azimuth_rad,
            b.azimuth_rad
        );
        assert!(
            (a.elevation_rad - LASER_ELEVATION_DEG[a.point.ring as usize].to_radians()).abs()
                < 1e-6
        );
    }
    assert!(s.complete && s.packets == 151);
    // Point times: firing order, except that the second echo of a dual pair shares its firing's
    // time (at most one pair, 110.6 us, back). Nebula's `time_stamp` is not compared: that build
    // timed dual-return blocks as if single-return (pair k at 4k sequences, up to 1.31 ms into a
    // packet that the sensor sends every 0.66 ms, as the packets' own timestamps show).
    assert!(s
        .returns
        .windows(2)
        .all(|w| w[1].point.t_s >= w[0].point.t_s - 110.6e-6));
    let t_end = s.returns.last().unwrap().point.t_s;
    println!("reference scan spans {t_end:.4} s");
    assert!((0.095..0.105).contains(&t_end));
}

#[test]
fn exact_interpolation_differs_from_nebula_only_by_its_azimuth_simplifications() {
    let Some(d) =
        data_dir("exact_interpolation_differs_from_nebula_only_by_its_azimuth_simplifications")
    else {
        return;
    };
    // Full azimuth window for both, so the same returns survive.
    let full = VelodyneConfig {
        max_azimuth_deg: 360.0,
        ..VelodyneConfig::nebula_reference()
    };
    let exact = VelodyneConfig {
        interpolation: AzimuthInterpolation::Exact,
        ..full
    };
    // Scans are cut by azimuth, which the two modes compute differently: compare whole streams.
    let all = |cfg| -> Vec<VelodyneReturn> {
        let (scans, _, _) = decode_file(bag_path(&d), cfg).unwrap();
        scans.into_iter().flat_map(|s| s.returns).collect()
    };
    let (a, b) = (all(full), all(exact));
    assert_eq!(a.len(), b.len());
    let mut errors: Vec<f64> = Vec::new();
    for (p, q) in a.iter().zip(&b) {
        assert_eq!((p.point.ring, p.distance_m), (q.point.ring, q.distance_m));
        // Nebula leaves odd blocks and the last pair uninterpolated: at most one pair step (~0.4 deg).
        let daz = (p.azimuth_rad - q.azimuth_rad).abs();
        let daz = daz.min(std::f32::consts::TAU - daz).to_degrees();
        assert!(daz < 0.45, "{daz} deg");
        let (p, q) = (p.point, q.point);
        errors.push(
            (((p.x - q.x).powi(2) + (p.y - q.y).powi(2) + (p.z - q.z).powi(2)) as f64).sqrt(),
        );
    }
    errors.sort_by(f64::total_cmp);
    let within_1cm = errors.iter().filter(|e| **e < 0.01).count();
    println!(
        "exact vs nebula azimuths: {} points, {} within 1 cm, median {:.4} m, max {:.4} m",
        errors.len(),
        within_1cm,
        errors[errors.len() / 2],
        errors[errors.len() - 1]
    );
    // 5 of 6 block pairs are interpolated identically (to nebula's 0.01 deg rounding).
    assert!(within_1cm as f64 > 0.75 * errors.len() as f64);
}

fn pcap_path(d: &std::path::Path) -> PathBuf {
    d.join("velodyne_vlp16.pcap")
}

/// The capture starts mid-rotation and holds ~1.03 rotations: cut where it starts. Its sensor
/// writes product id 0x21 (early VLP-16 firmware): see `require_vlp16_product`.
fn from_stream_start() -> VelodyneConfig {
    VelodyneConfig {
        cut_angle_deg: None,
        require_vlp16_product: false,
        ..VelodyneConfig::default()
    }
}

#[test]
fn pcap_decodes_into_a_plausible_full_rotation() {
    let Some(d) = data_dir("pcap_decodes_into_a_plausible_full_rotation") else {
        return;
    };
    let (scans, stats, fstats) = decode_file(pcap_path(&d), from_stream_start()).unwrap();
    println!("pcap: {stats:?} {fstats:?}");
    for s in &scans {
        println!(
            "scan {}: {} points, {} packets, coverage {:.2} deg, complete {}",
            s.index,
            s.returns.len(),
            s.packets,
            s.coverage_deg,
            s.complete
        );
    }
    assert_eq!((stats.packets_ok, stats.malformed()), (84, 0));
    let (_, strict, _) = decode_file(pcap_path(&d), VelodyneConfig::default()).unwrap();
    assert_eq!((strict.packets_ok, strict.unknown_product), (0, 84));
    // The 16 position packets go to port 8308 and are filtered out by port.
    assert_eq!(fstats.pcap.other_port, 16);
    let s = &scans[0];
    assert!(s.complete && (s.coverage_deg - 360.0).abs() < 1e-9);
    let pts = s.to_scan().points;
    let mut rings = [0usize; 16];
    let mut az_bins = vec![false; 360];
    let mut ranges: Vec<f32> = Vec::new();
    for r in &s.returns {
        rings[r.point.ring as usize] += 1;
        az_bins[(r.azimuth_rad.to_degrees() as usize).min(359)] = true;
        ranges.push(r.distance_m);
    }
    ranges.sort_by(f32::total_cmp);
    let bins = az_bins.iter().filter(|b| **b).count();
    println!(
        "pcap scan 0: {} points, per laser {:?}, azimuth bins hit {bins}/360, range min {:.2} median {:.2} max {:.2} m",
        pts.len(),
        rings,
        ranges[0],
        ranges[ranges.len() / 2],
        ranges[ranges.len() - 1]
    );
    assert!(
        rings.iter().all(|n| *n > 100),
        "all 16 lasers return: {rings:?}"
    );
    assert!(bins >= 355, "{bins}");
    assert!(ranges[0] > 0.3 && ranges[ranges.len() - 1] < 130.0);
    // A ground plane below the sensor: RANSAC over the returns below the sensor's height.
    let below: Vec<[f64; 3]> = pts
        .iter()
        .filter(|p| p.z < 0.0)
        .map(|p| [p.x as f64, p.y as f64, p.z as f64])
        .collect();
    let (inliers, normal, height_m) = ground_plane(&below);
    println!(
        "ground plane: {inliers} of {} returns below the sensor within 10 cm, height {height_m:.2} m, tilt {:.1} deg",
        below.len(),
        normal[2].acos().to_degrees()
    );
    assert!(normal[2].acos().to_degrees() < 10.0);
    assert!((0.5..3.0).contains(&height_m), "{height_m}");
    assert!(inliers * 10 > below.len() * 3, "{inliers}");
    // Time runs across the rotation: ~0.1 s at 10 Hz.
    let t_end = s.returns.last().unwrap().point.t_s;
    println!("rotation time {t_end:.4} s");
    assert!((0.05..0.25).contains(&t_end), "{t_end}");
}

/// Best plane through 3 of the points with a near-vertical normal (deterministic RANSAC): inlier
/// count (10 cm), unit normal (z up) and the sensor's height above it.
fn ground_plane(p: &[[f64; 3]]) -> (usize, [f64; 3], f64) {
    let mut best = (0, [0.0, 0.0, 1.0], 0.0);
    let mut seed = 12345u64;
    let mut pick = || {
        seed = seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        p[(seed >> 33) as usize % p.len()]
    };
    for _ in 0..400 {
        let (a, b, c) = (pick(), pick(), pick());
        let u = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
        let v = [c[0] - a[0], c[1] - a[1], c[2] - a[2]];
        let mut n = [
            u[1] * v[2] - u[2] * v[1],
            u[2] * v[0] - u[0] * v[2],
            u[0] * v[1] - u[1] * v[0],
        ];
        let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
        if len < 1e-9 {
            continue;
        }
        let sign = if n[2] < 0.0 { -1.0 } else { 1.0 };
        n = [sign * n[0] / len, sign * n[1] / len, sign * n[2] / len];
        if n[2] < 0.9 {
            continue;
        }
        let d = -(n[0] * a[0] + n[1] * a[1] + n[2] * a[2]);
        let count = p
            .iter()
            .filter(|q| (n[0] * q[0] + n[1] * q[1] + n[2] * q[2] + d).abs() < 0.1)
            .count();
        if count > best.0 {
            best = (count, n, d);
        }
    }
    best
}

fn pcap_packets(d: &std::path::Path) -> Vec<(f64, Vec<u8>)> {
    let mut f = PacketFile::open(pcap_path(d), None, None).unwrap();
    let mut v = Vec::new();
    while let Some(p) = f.next_packet().unwrap() {
        v.push((p.stamp_s, p.data));
    }
    v
}

#[test]
fn live_udp_socket_decodes_the_same_scan_as_the_file() {
    let Some(d) = data_dir("live_udp_socket_decodes_the_same_scan_as_the_file") else {
        return;
    };
    let packets = pcap_packets(&d);
    assert_eq!(packets.len(), 84);
    let (from_file, _, _) = decode_file(pcap_path(&d), from_stream_start()).unwrap();
    let mut rx = UdpScanSource::bind("127.0.0.1:0".parse().unwrap(), from_stream_start()).unwrap();
    let to = rx.local_addr().unwrap();
    let sender = std::thread::spawn(move || {
        let tx = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
        for (i, (_, p)) in packets.iter().enumerate() {
            tx.send_to(p, to).unwrap();
            // Paced like a sensor in bursts, so the receive buffer never overflows.
            if i % 8 == 7 {
                std::thread::sleep(Duration::from_millis(1));
            }
        }
    });
    let live = rx
        .next_scan(Duration::from_secs(10))
        .unwrap()
        .expect("a scan within 10 s");
    sender.join().unwrap();
    let rest = rx.next_scan(Duration::from_millis(200)).unwrap();
    assert!(rest.is_none(), "the capture holds one full rotation");
    let tail = rx.flush().expect("the partial rotation after the cut");
    assert_eq!(rx.datagrams, 84);
    assert_eq!(rx.stats().packets_ok, 84);
    let f = &from_file[0];
    assert!(live.complete);
    assert_eq!(
        (live.returns.len(), live.packets),
        (f.returns.len(), f.packets)
    );
    // Same returns bit for bit, point times included (they come from the sensor clock).
    assert_eq!(live.returns, f.returns);
    assert_eq!(tail.returns, from_file[1].returns);
    println!(
        "live UDP: scan of {} points from {} packets, identical to the file",
        live.returns.len(),
        live.packets
    );
}

#[test]
fn malformed_real_packets_are_counted_and_skipped() {
    let Some(d) = data_dir("malformed_real_packets_are_counted_and_skipped") else {
        return;
    };
    let packets = pcap_packets(&d);
    let mut asm = ScanAssembler::new(from_stream_start());
    let (mut expect_points, mut total) = (0, 0);
    let cfg = from_stream_start();
    for (i, (t, p)) in packets.iter().enumerate() {
        let mut q = p.clone();
        match i % 10 {
            1 => q.truncate(1000),                                     // wrong size
            2 => q[700] = 0x00,                                        // block 7 flag
            3 => q[1204] = 0x40,                                       // return mode
            4 => q[502..504].copy_from_slice(&40000u16.to_le_bytes()), // azimuth
            5 => q.extend_from_slice(&[0; 6]),                         // wrong size
            _ => {
                let mut out = Vec::new();
                sensing::velodyne::decode_packet(&q, &cfg, &mut out).unwrap();
                expect_points += out.len();
            }
        }
        total += asm
            .push_packet(&q, *t)
            .iter()
            .map(|s| s.returns.len())
            .sum::<usize>();
    }
    total += asm.finish().map_or(0, |s| s.returns.len());
    let st = asm.stats().clone();
    println!("malformed: {st:?}");
    assert_eq!(
        (
            st.wrong_size,
            st.bad_block_flag,
            st.unknown_return_mode,
            st.bad_azimuth
        ),
        (17, 9, 9, 8)
    );
    assert_eq!(st.packets_ok + st.malformed(), 84);
    // Every return of every good packet lands in exactly one scan.
    assert_eq!(total, expect_points);
}

#[test]
fn corrupt_bag_messages_are_typed_errors() {
    let Some(d) = data_dir("corrupt_bag_messages_are_typed_errors") else {
        return;
    };
    let mut bag = BagReader::open(bag_path(&d), None).unwrap();
    assert_eq!((bag.topic.as_str(), bag.len()), ("/velodyne_packets", 4));
    let (t_ns, msg) = bag.next_message().unwrap().unwrap();
    let msg = msg.unwrap();
    assert_eq!(t_ns, 1_673_400_471_837_873_222);
    assert_eq!(
        (msg.frame_id.as_str(), msg.packets.len()),
        ("velodyne", 151)
    );
    let blob = sensing::velodyne::rosbag::encode_velodyne_scan(&msg);
    // Re-encoding reproduces the recorded CDR length (alignment and padding as rosbag2 wrote it).
    assert_eq!(blob.len(), 183_648);
    for cut in [0, 3, 20, 31, 1000, blob.len() - 100] {
        assert!(
            matches!(
                decode_velodyne_scan(&blob[..cut]),
                Err(CdrError::Truncated { .. })
            ),
            "{cut}"
        );
    }
    assert!(BagReader::open(bag_path(&d), Some("/nope")).is_err());
    assert!(PacketFile::open(pcap_path(&d), None, Some("/x")).is_ok());
    assert!(PacketFile::open(d.join("packets_metadata.yaml"), None, None).is_err());
}
