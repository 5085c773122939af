//! What the secure-link tests share: the fleet's `pki` command, the secure loopback endpoint, a
//! plain pose and a pump that publishes it. Their own Zenoh sessions with chosen certificates are
//! `station_support::Observer`s.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;

use common::msg::Pose;
use serde_json::Value;
use support::bin;

use crate::station_support::now_ms;

/// The secure endpoint of a loopback port: the one place the tests choose the scheme.
pub fn secure_ep(port: u16) -> String {
    format!("{}/127.0.0.1:{port}", common::security::SECURE_SCHEME)
}

/// `operator-station pki ARGS`, asserting success; its JSON line.
pub fn pki(args: &[&str]) -> Value {
    let out = Command::new(bin("operator-station"))
        .arg("pki")
        .args(args)
        .output()
        .expect("run operator-station pki");
    assert!(
        out.status.success(),
        "pki {args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = String::from_utf8_lossy(&out.stdout);
    serde_json::from_str(text.trim()).unwrap_or_else(|e| panic!("{e}: {text}"))
}

/// A fleet in `dir/name` with certificates for `robots`.
pub fn fleet(dir: &Path, name: &str, robots: &[&str]) -> PathBuf {
    let p = dir.join(name);
    let ps = p.to_str().expect("utf-8 path");
    pki(&["init", "--dir", ps]);
    for r in robots {
        pki(&["issue", "--robot", r, "--dir", ps]);
    }
    p
}

/// A pose at (`x_m`, 0), stamped now.
pub fn pose(seq: u32, x_m: f64) -> Pose {
    Pose {
        t_unix_ms: now_ms(),
        seq,
        x_m,
        y_m: 0.0,
        z_m: 0.0,
        yaw_rad: 0.0,
        pitch_rad: 0.0,
        roll_rad: 0.0,
        v_mps: 0.0,
        omega_rps: 0.0,
        fix: Default::default(),
        lat_lon_deg: None,
    }
}

/// Publishes a pose at (`x_m`, 0), stamped with the wall clock, at 10 Hz from a thread of its own
/// until dropped.
pub struct PosePump {
    stop: Arc<AtomicBool>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl PosePump {
    /// Starts the pump: `open` runs first on the pump's thread (so it may enter a namespace or
    /// open a session there) and returns what publishes each pose.
    pub fn start<P: FnMut(&Pose)>(x_m: f64, open: impl FnOnce() -> P + Send + 'static) -> Self {
        let stop = Arc::new(AtomicBool::new(false));
        let s = stop.clone();
        let thread = std::thread::spawn(move || {
            let mut publish = open();
            let mut seq = 0;
            while !s.load(Ordering::Relaxed) {
                publish(&pose(seq, x_m));
                seq += 1;
                std::thread::sleep(Duration::from_millis(100));
            }
        });
        Self {
            stop,
            thread: Some(thread),
        }
    }
}

impl Drop for PosePump {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}
