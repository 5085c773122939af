use super::packet::tests::synthetic;
use super::*;

#[test]
fn laser_rings() {
    let mut seen: Vec<(f32, u16)> = (0..16)
        .map(|i| (LASER_ELEVATION_DEG[i], ring_by_elevation(i as u16)))
        .collect();
    seen.sort_by(|a, b| a.0.total_cmp(&b.0));
    assert_eq!(
        seen.iter().map(|s| s.1).collect::<Vec<_>>(),
        (0..16).collect::<Vec<u16>>()
    );
}

/// A stream of single-return packets turning 0.2 deg per block from `start_cdeg`.
fn stream(start_cdeg: u32, n: usize) -> Vec<Vec<u8>> {
    (0..n)
        .map(|i| {
            let az = ((start_cdeg + 240 * i as u32) % 36000) as u16;
            let mut p = synthetic(0x37, az, 20, 2000);
            let t = (1_000_000 + i as u32 * 1327).to_le_bytes();
            p[1200..1204].copy_from_slice(&t);
            p
        })
        .collect()
}

#[test]
fn cuts_at_the_cut_angle_and_times_points() {
    // 0.2 deg per block, 2.4 deg per packet: 150 packets a rotation; start at 100 deg.
    let pk = stream(10_000, 500);
    let (scans, stats) = assemble_all(pk.iter().map(|p| (&p[..], 0.0)), VelodyneConfig::default());
    assert_eq!(stats.packets_ok, 500);
    // 100..360 partial, two full rotations, then the rest.
    assert_eq!(scans.len(), 4);
    let flags: Vec<(bool, usize)> = scans.iter().map(|s| (s.complete, s.packets)).collect();
    assert_eq!(flags, [(false, 109), (true, 151), (true, 151), (false, 92)]);
    let s = &scans[1];
    assert_eq!(s.returns.len(), 150 * 384);
    assert!((s.coverage_deg - 360.0).abs() < 0.3, "{}", s.coverage_deg);
    assert!(s.returns[0].azimuth_rad < 0.001);
    assert!(s.returns.last().unwrap().azimuth_rad.to_degrees() > 359.7);
    assert_eq!(s.returns[0].point.t_s, 0.0);
    // 150 packets of 24 sequences.
    let t_end = s.returns.last().unwrap().point.t_s as f64;
    assert!(
        (t_end - (149.0 * 1327e-6 + 23.0 * 55.296e-6 + 15.0 * 2.304e-6)).abs() < 1e-6,
        "{t_end}"
    );
    assert!(s
        .returns
        .windows(2)
        .all(|w| w[1].point.t_s >= w[0].point.t_s));
    assert_eq!(s.to_scan().points.len(), s.returns.len());
}

#[test]
fn cut_at_stream_start_gives_a_full_first_rotation() {
    let pk = stream(25_000, 151);
    let cfg = VelodyneConfig {
        cut_angle_deg: None,
        ..VelodyneConfig::default()
    };
    let (scans, _) = assemble_all(pk.iter().map(|p| (&p[..], 5.0)), cfg);
    assert_eq!(scans.len(), 2);
    assert!(scans[0].complete);
    assert_eq!(scans[0].packets, 150);
    assert_eq!(scans[0].returns.len(), 150 * 384);
    assert_eq!(scans[0].stamp_s, 5.0);
}

#[test]
fn hour_wrap_of_the_sensor_clock() {
    let mut pk = stream(0, 3);
    for (i, p) in pk.iter_mut().enumerate() {
        let t = (3_599_999_000u32 + i as u32 * 1327) % 3_600_000_000;
        p[1200..1204].copy_from_slice(&t.to_le_bytes());
    }
    let (scans, _) = assemble_all(pk.iter().map(|p| (&p[..], 0.0)), VelodyneConfig::default());
    let t = scans[0].returns.last().unwrap().point.t_s as f64;
    assert!(
        (t - (2.0 * 1327e-6 + 23.0 * 55.296e-6 + 15.0 * 2.304e-6)).abs() < 1e-6,
        "{t}"
    );
}

#[test]
fn malformed_packets_are_counted_and_skipped() {
    let pk = stream(0, 10);
    let mut asm = ScanAssembler::new(VelodyneConfig::default());
    let mut bad_flag = pk[3].clone();
    bad_flag[500] = 0x00;
    let mut bad_product = pk[4].clone();
    bad_product[1205] = 0xA1;
    for (i, p) in pk.iter().enumerate() {
        match i {
            3 => asm.push_packet(&bad_flag, 0.0),
            4 => asm.push_packet(&bad_product, 0.0),
            5 => asm.push_packet(&p[..512], 0.0),
            _ => asm.push_packet(p, 0.0),
        };
    }
    let s = asm.finish().unwrap();
    let st = asm.stats();
    assert_eq!(
        (
            st.packets_ok,
            st.bad_block_flag,
            st.unknown_product,
            st.wrong_size
        ),
        (7, 1, 1, 1)
    );
    assert_eq!(st.malformed(), 3);
    assert_eq!(s.returns.len(), 7 * 384);
    assert_eq!(s.packets, 7);
}

#[test]
fn a_gap_in_the_sensor_clock_closes_the_scan() {
    let mut pk = stream(0, 200);
    // Packets 60.. arrive 2 s later, from another azimuth (the sensor kept turning).
    for (i, p) in pk.iter_mut().enumerate().skip(60) {
        let t = 3_000_000 + i as u32 * 1327;
        p[1200..1204].copy_from_slice(&t.to_le_bytes());
        for b in 0..12 {
            let az = ((20_000 + 240 * (i as u32 - 60) + 20 * b as u32) % 36000) as u16;
            p[b * 100 + 2..b * 100 + 4].copy_from_slice(&az.to_le_bytes());
        }
    }
    let (scans, stats) = assemble_all(pk.iter().map(|p| (&p[..], 0.0)), VelodyneConfig::default());
    assert_eq!(stats.time_gaps, 1);
    assert_eq!(stats.malformed(), 0);
    assert!(!scans[0].complete);
    assert_eq!(scans[0].packets, 60);
    // After the gap: from 200 deg at 2.4 deg a packet, the 360 deg cut comes in the 67th.
    assert_eq!(scans[1].packets, 67);
    assert!(scans[1].returns.iter().all(|r| r.point.t_s < 0.1));
}
