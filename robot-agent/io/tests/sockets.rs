//! NMEA over real TCP and UDP sockets on loopback, and the CDR decoders against garbage.

use std::time::Duration;

use common::geo::nmea::frame;
use io::gnss::{GnssEvent, LineSource, NmeaDecoder};
use io::sample::FixStatus;
use proptest::prelude::*;
use tokio::io::AsyncWriteExt;

/// Guards a read so a broken source fails the test instead of hanging it (not a speed check).
async fn within<T>(f: impl std::future::Future<Output = T>) -> T {
    tokio::time::timeout(Duration::from_secs(20), f)
        .await
        .expect("source delivered nothing for 20 s")
}

fn lines() -> Vec<String> {
    vec![
        frame("GNGGA,132819.60,4134.49795459,N,09345.03431408,W,4,10,0.9,278.161,M,-31.442,M,6.6,0133"),
        "$GNGGA,bad*00".to_owned(),
        frame("GNHDT,12.5,T"),
        frame("GNGGA,132819.70,,,,,0,00,,,M,,M,,"),
    ]
}

async fn check(mut src: LineSource) {
    let mut dec = NmeaDecoder::new();
    let mut events = Vec::new();
    while events.len() < 3 {
        let line = within(src.next_line())
            .await
            .unwrap()
            .expect("stream ended early");
        events.extend(dec.feed(&line, 1.0));
    }
    let GnssEvent::Fix(f) = &events[0] else {
        panic!("{events:?}")
    };
    assert_eq!(f.status, FixStatus::Gbas);
    assert!((f.lat_deg - (41.0 + 34.49795459 / 60.0)).abs() < 1e-12);
    assert!((f.lon_deg + (93.0 + 45.03431408 / 60.0)).abs() < 1e-12);
    assert!((f.alt_m - (278.161 - 31.442)).abs() < 1e-9);
    assert!(matches!(&events[1], GnssEvent::Heading(h) if h.heading_deg == 12.5));
    assert!(matches!(&events[2], GnssEvent::Fix(f) if f.status == FixStatus::NoFix));
    assert_eq!(dec.stats().refused_total(), 1);
}

#[tokio::test]
async fn nmea_over_tcp() {
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let port = listener.local_addr().unwrap().port();
    let server = tokio::spawn(async move {
        let (mut s, _) = listener.accept().await.unwrap();
        for l in lines() {
            s.write_all(format!("{l}\r\n").as_bytes()).await.unwrap();
        }
        s.flush().await.unwrap();
        // Keep the connection open until the reader is done.
        tokio::time::sleep(Duration::from_secs(30)).await;
    });
    check(LineSource::tcp("127.0.0.1", port).await.unwrap()).await;
    server.abort();
}

#[tokio::test]
async fn nmea_over_udp() {
    let src = LineSource::udp(0).await.unwrap();
    let port = src.local_port().unwrap();
    let tx = tokio::net::UdpSocket::bind("127.0.0.1:0").await.unwrap();
    let l = lines();
    // Two lines in one datagram, then one each (receivers do both).
    tx.send_to(
        format!("{}\r\n{}\r\n", l[0], l[1]).as_bytes(),
        ("127.0.0.1", port),
    )
    .await
    .unwrap();
    tx.send_to(l[2].as_bytes(), ("127.0.0.1", port))
        .await
        .unwrap();
    tx.send_to(l[3].as_bytes(), ("127.0.0.1", port))
        .await
        .unwrap();
    check(src).await;
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 2000, ..ProptestConfig::default() })]

    /// Random bytes after a valid header: every decoder answers Ok or a typed error.
    #[test]
    fn garbage_never_panics(body in proptest::collection::vec(any::<u8>(), 0..600), be in any::<bool>()) {
        let mut m = vec![0, if be { 0 } else { 1 }, 0, 0];
        m.extend_from_slice(&body);
        let _ = io::cdr::decode_point_cloud2(&m);
        let _ = io::cdr::decode_odometry(&m);
        let _ = io::cdr::decode_imu(&m);
        let _ = io::cdr::decode_nav_sat_fix(&m);
        let _ = io::cdr::decode_twist(&m);
        let _ = io::cdr::decode_tf_message(&m);
        let _ = io::cdr::decode_heading_quaternion(&m);
        let _ = io::ros2::Attachment::decode(&body);
        let _ = io::gnss::decode_gpsd_report(&String::from_utf8_lossy(&body), 0.0);
    }

    /// A valid cloud with bytes flipped: Ok or a typed error, never a panic.
    #[test]
    fn corrupted_cloud_never_panics(flips in proptest::collection::vec((any::<usize>(), any::<u8>()), 1..8)) {
        let c = io::sample::Cloud {
            stamp_s: 5.0,
            frame_id: "velodyne".into(),
            points: vec![[1.0, 2.0, 3.0]; 20],
            intensity: Some(vec![1.0; 20]),
            ring: Some(vec![2; 20]),
            time_s: Some(vec![0.01; 20]),
            dropped_non_finite: 0,
        };
        let mut m = io::cdr::encode_point_cloud2(&c);
        for (i, v) in flips {
            let n = m.len();
            m[i % n] ^= v;
        }
        let _ = io::cdr::decode_point_cloud2(&m);
    }
}
