//! `terranav-linkemu IF_A IF_B`: a link emulator for the network-namespace tests (tests/netns.rs),
//! for kernels without `tc netem`. It runs in a "link" namespace holding one end of two veth
//! pairs and bridges them at layer 2 through AF_PACKET sockets: every frame read on one side is
//! written to the other after a one-way delay, dropped with a probability, and all frames are
//! dropped while the link is cut. Frames keep their order (the delay is the same for all).
//!
//! Commands on standard input, one a line: `delay_ms N` (one way, each direction), `loss P`
//! (0..1, each direction), `cut on|off`, `stats` (one JSON line on standard output). It prints
//! `ready` once both sides are open, and exits when standard input closes (the test is gone).
//!
//! The veth ends that send into the emulator must not offload segmentation (`ip link set DEV
//! gso_max_segs 1`: every frame is at most one MTU, as on a wire, so loss is per frame). Their
//! TCP and UDP checksums are left to the "hardware" (the checksum is partial), so the emulator
//! fills them in, as a NIC would, before it writes a frame to the other side.

use std::io::{BufRead, Write};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{mpsc, Arc};
use std::time::{Duration, Instant};

use pnet_datalink::{Channel, Config, DataLinkReceiver, DataLinkSender};

/// What the test controls.
#[derive(Default)]
struct Params {
    delay_us: AtomicU64,
    /// Loss probability in parts per million.
    loss_ppm: AtomicU64,
    cut: AtomicBool,
}

/// Frames of one direction.
#[derive(Default)]
struct Counters {
    forwarded: AtomicU64,
    lost: AtomicU64,
    cut: AtomicU64,
    errors: AtomicU64,
}

impl Counters {
    fn json(&self) -> serde_json::Value {
        serde_json::json!({
            "forwarded": self.forwarded.load(Ordering::Relaxed),
            "lost": self.lost.load(Ordering::Relaxed),
            "cut": self.cut.load(Ordering::Relaxed),
            "errors": self.errors.load(Ordering::Relaxed),
        })
    }
}

/// xorshift64*: the loss draws (no need for more; seeded per direction).
struct Rng(u64);

impl Rng {
    /// Uniform in 0..1_000_000.
    fn ppm(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        (self.0.wrapping_mul(0x2545_f491_4f6c_dd1d) >> 11) % 1_000_000
    }
}

fn open(name: &str) -> anyhow::Result<(Box<dyn DataLinkSender>, Box<dyn DataLinkReceiver>)> {
    let iface = pnet_datalink::interfaces()
        .into_iter()
        .find(|i| i.name == name)
        .ok_or_else(|| anyhow::anyhow!("no interface {name} in this namespace"))?;
    let cfg = Config {
        read_buffer_size: 70_000,
        write_buffer_size: 70_000,
        // The receive loop wakes up now and then to notice nothing (no busy wait).
        read_timeout: Some(Duration::from_millis(200)),
        promiscuous: true,
        ..Config::default()
    };
    match pnet_datalink::channel(&iface, cfg)? {
        Channel::Ethernet(tx, rx) => Ok((tx, rx)),
        _ => anyhow::bail!("{name}: not an Ethernet channel"),
    }
}

/// One's-complement sum of 16-bit big-endian words.
fn sum16(data: &[u8], mut acc: u32) -> u32 {
    let mut chunks = data.chunks_exact(2);
    for c in &mut chunks {
        acc += u32::from(u16::from_be_bytes([c[0], c[1]]));
    }
    if let [last] = chunks.remainder() {
        acc += u32::from(*last) << 8;
    }
    acc
}

fn fold(mut acc: u32) -> u16 {
    while acc >> 16 != 0 {
        acc = (acc & 0xffff) + (acc >> 16);
    }
    !(acc as u16)
}

/// Fills in the TCP or UDP checksum of an IPv4 frame (what a NIC does with a partial checksum;
/// a complete one comes out the same). Other frames are left as they are.
fn fill_checksum(f: &mut [u8]) {
    if f.len() < 34 || f[12..14] != [0x08, 0x00] {
        return;
    }
    let ip = &f[14..];
    let ihl = usize::from(ip[0] & 0x0f) * 4;
    let total = usize::from(u16::from_be_bytes([ip[2], ip[3]]));
    let fragmented = u16::from_be_bytes([ip[6], ip[7]]) & 0x3fff != 0;
    if ihl < 20 || total < ihl || 14 + total > f.len() || fragmented {
        return;
    }
    let proto = ip[9];
    let at = match proto {
        6 => 16,
        17 => 6,
        _ => return,
    };
    let (l4_start, l4_end) = (14 + ihl, 14 + total);
    if l4_end - l4_start < at + 2 {
        return;
    }
    if proto == 17 && f[l4_start + 6..l4_start + 8] == [0, 0] {
        return; // UDP without a checksum
    }
    f[l4_start + at] = 0;
    f[l4_start + at + 1] = 0;
    let mut acc = sum16(&f[26..34], 0); // source and destination address
    acc += u32::from(proto) + (l4_end - l4_start) as u32;
    acc = sum16(&f[l4_start..l4_end], acc);
    let mut c = fold(acc);
    if proto == 17 && c == 0 {
        c = 0xffff;
    }
    f[l4_start + at..l4_start + at + 2].copy_from_slice(&c.to_be_bytes());
}

/// Reads frames from `rx` and hands them, due at their delivery time, to a writer thread.
fn direction(
    mut rx: Box<dyn DataLinkReceiver>,
    mut tx: Box<dyn DataLinkSender>,
    p: Arc<Params>,
    c: Arc<Counters>,
    seed: u64,
) {
    let (q_tx, q_rx) = mpsc::channel::<(Instant, Vec<u8>)>();
    let (p2, c2) = (p.clone(), c.clone());
    std::thread::spawn(move || {
        while let Ok((due, frame)) = q_rx.recv() {
            let now = Instant::now();
            if due > now {
                std::thread::sleep(due - now);
            }
            // A frame in flight when the link is cut is lost with it.
            if p2.cut.load(Ordering::Relaxed) {
                c2.cut.fetch_add(1, Ordering::Relaxed);
                continue;
            }
            match tx.send_to(&frame, None) {
                Some(Ok(())) => c2.forwarded.fetch_add(1, Ordering::Relaxed),
                _ => c2.errors.fetch_add(1, Ordering::Relaxed),
            };
        }
    });
    std::thread::spawn(move || {
        let mut rng = Rng(seed | 1);
        loop {
            let frame = match rx.next() {
                Ok(f) => f,
                Err(e) if e.kind() == std::io::ErrorKind::TimedOut => continue,
                Err(_) => {
                    c.errors.fetch_add(1, Ordering::Relaxed);
                    std::thread::sleep(Duration::from_millis(10));
                    continue;
                }
            };
            if p.cut.load(Ordering::Relaxed) {
                c.cut.fetch_add(1, Ordering::Relaxed);
                continue;
            }
            if rng.ppm() < p.loss_ppm.load(Ordering::Relaxed) {
                c.lost.fetch_add(1, Ordering::Relaxed);
                continue;
            }
            let mut f = frame.to_vec();
            fill_checksum(&mut f);
            let due = Instant::now() + Duration::from_micros(p.delay_us.load(Ordering::Relaxed));
            if q_tx.send((due, f)).is_err() {
                return;
            }
        }
    });
}

/// Applies one command line; an error names what was wrong.
fn command(line: &str, p: &Params, ab: &Counters, ba: &Counters) -> Result<(), String> {
    let mut w = line.split_whitespace();
    let (Some(cmd), arg) = (w.next(), w.next()) else {
        return Ok(());
    };
    let num = |a: Option<&str>| -> Result<f64, String> {
        a.and_then(|s| s.parse::<f64>().ok())
            .filter(|v| v.is_finite() && *v >= 0.0)
            .ok_or_else(|| format!("{cmd}: want a number >= 0, got {a:?}"))
    };
    match cmd {
        "delay_ms" => p
            .delay_us
            .store((num(arg)? * 1000.0) as u64, Ordering::Relaxed),
        "loss" => p
            .loss_ppm
            .store((num(arg)?.min(1.0) * 1e6) as u64, Ordering::Relaxed),
        "cut" => match arg {
            Some("on") => p.cut.store(true, Ordering::Relaxed),
            Some("off") => p.cut.store(false, Ordering::Relaxed),
            _ => return Err(format!("cut: want on or off, got {arg:?}")),
        },
        "stats" => {
            let out = serde_json::json!({"a_to_b": ab.json(), "b_to_a": ba.json()});
            let mut o = std::io::stdout().lock();
            let _ = writeln!(o, "{out}");
            let _ = o.flush();
        }
        _ => return Err(format!("unknown command {cmd}")),
    }
    Ok(())
}

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [a, b] = args.as_slice() else {
        anyhow::bail!("usage: terranav-linkemu IF_A IF_B (commands on standard input)");
    };
    let (tx_a, rx_a) = open(a)?;
    let (tx_b, rx_b) = open(b)?;
    let p = Arc::new(Params::default());
    let (ab, ba) = (Arc::new(Counters::default()), Arc::new(Counters::default()));
    direction(rx_a, tx_b, p.clone(), ab.clone(), 0x9e37_79b9_7f4a_7c15);
    direction(rx_b, tx_a, p.clone(), ba.clone(), 0xd1b5_4a32_d192_ed03);
    println!("ready");
    std::io::stdout().flush()?;
    for line in std::io::stdin().lock().lines() {
        let line = line?;
        if let Err(e) = command(&line, &p, &ab, &ba) {
            eprintln!("terranav-linkemu: {e}");
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn checksum_of_a_known_udp_frame() {
        // Ethernet + IPv4 (10.0.0.1 -> 10.0.0.2) + UDP 1000 -> 2000 with payload "hi".
        let mut f = vec![0u8; 14];
        f[12..14].copy_from_slice(&[0x08, 0x00]);
        f.extend_from_slice(&[
            0x45, 0, 0, 30, 0, 0, 0x40, 0, 64, 17, 0, 0, 10, 0, 0, 1, 10, 0, 0, 2,
        ]);
        f.extend_from_slice(&[0x03, 0xe8, 0x07, 0xd0, 0, 10, 0x12, 0x34, b'h', b'i']);
        fill_checksum(&mut f);
        // Verifying: the sum over pseudo-header and datagram, checksum included, folds to 0.
        let mut acc = sum16(&f[26..34], 0) + 17 + 10;
        acc = sum16(&f[34..44], acc);
        assert_eq!(fold(acc), 0);
        assert_ne!(&f[40..42], &[0x12, 0x34]);
    }
}
