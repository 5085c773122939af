//! VLP-16 decoding speed on the real bag (603 dual-return packets) and pcap (84 single-return).
//!
//! Baseline in the same run: `inspect` (size, flags, azimuths, mode and product checks only),
//! against `decode` (returns in the sensor frame) and `assemble` (decode + scan cutting + timing).
//! Report packets/s and the ratio to the baseline. Without `../shared/data` it benchmarks
//! synthetic packets instead.

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use sensing::velodyne::source::PacketFile;
use sensing::velodyne::{decode_packet, inspect_packet, ScanAssembler, VelodyneConfig};
use std::hint::black_box;
use std::path::PathBuf;

fn packets(name: &str) -> Option<Vec<Vec<u8>>> {
    let p = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../../shared/data/lidar/vlp16")
        .join(name);
    let mut f = PacketFile::open(&p, None, None).ok()?;
    let mut v = Vec::new();
    while let Ok(Some(pk)) = f.next_packet() {
        v.push(pk.data);
    }
    Some(v)
}

fn bench(c: &mut Criterion) {
    let cfg = VelodyneConfig {
        require_vlp16_product: false,
        ..VelodyneConfig::default()
    };
    let sets = [
        ("bag_dual", "packets_1673400471837873222.db3"),
        ("pcap_strongest", "velodyne_vlp16.pcap"),
    ];
    for (label, file) in sets {
        let Some(pk) = packets(file) else {
            println!("skipping {label}: ../shared/data is absent");
            continue;
        };
        let mut g = c.benchmark_group(label);
        g.throughput(Throughput::Elements(pk.len() as u64));
        g.bench_function("inspect", |b| {
            b.iter(|| {
                pk.iter()
                    .filter(|p| inspect_packet(black_box(p), false).is_ok())
                    .count()
            })
        });
        let mut out = Vec::with_capacity(400);
        g.bench_function("decode", |b| {
            b.iter(|| {
                let mut n = 0;
                for p in &pk {
                    out.clear();
                    let _ = decode_packet(black_box(p), &cfg, &mut out);
                    n += out.len();
                }
                n
            })
        });
        g.bench_function("assemble", |b| {
            b.iter(|| {
                let mut asm = ScanAssembler::new(cfg);
                let mut n = 0;
                for (i, p) in pk.iter().enumerate() {
                    n += asm.push_packet(black_box(p), i as f64 * 1.3e-3).len();
                }
                n + asm.finish().map_or(0, |s| s.returns.len())
            })
        });
        g.finish();
    }
}

criterion_group!(benches, bench);
criterion_main!(benches);
