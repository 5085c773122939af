//! What the secure-link tests share: the fleet's `pki` command, the secure loopback endpoint, a
//! plain pose, and a Zenoh session of the test itself with chosen certificates (an operator, a
//! monitor, an intruder) that can link, listen, and put commands.
#![allow(dead_code)]

use std::path::Path;
use std::process::Command;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use common::command::CommandStamper;
use common::msg::{self, GoalCmd, GoalTarget, Pose};
use serde_json::Value;
use support::bin;

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

fn unix_ms() -> u64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| d.as_millis() as u64)
}

/// A pose at (`x_m`, 0), stamped now.
pub fn pose(seq: u32, x_m: f64) -> Pose {
    Pose {
        t_unix_ms: unix_ms(),
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

/// The certificates a test session presents: the CA it trusts (none: plain links only) and its
/// own certificate and key (none: no client certificate).
#[derive(Clone, Copy, Default)]
pub struct Tls<'a> {
    /// The CA to trust.
    pub ca: Option<&'a Path>,
    /// Certificate and key to present.
    pub identity: Option<(&'a Path, &'a Path)>,
}

impl<'a> Tls<'a> {
    /// A fleet member's files: its CA, certificate and key.
    pub fn member(files: &'a common::security::CertFiles) -> Self {
        Tls {
            ca: Some(&files.ca),
            identity: Some((&files.cert, &files.key)),
        }
    }
}

/// A Zenoh session of the test, as a client (served by what it connects to) or a peer (linked
/// straight to each endpoint).
pub struct TestSession {
    rt: tokio::runtime::Runtime,
    /// The session.
    pub session: zenoh::Session,
}

impl TestSession {
    /// Opens the session; panics when it cannot.
    pub fn open(connect: &[String], tls: Tls, client: bool) -> TestSession {
        Self::try_open(connect, tls, client).expect("open zenoh")
    }

    /// As [`TestSession::open`]; a client that cannot link fails to open.
    pub fn try_open(connect: &[String], tls: Tls, client: bool) -> Result<TestSession, String> {
        let rt = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(1)
            .enable_all()
            .build()
            .expect("runtime");
        let mut c = operator_station::station::zenoh_config(None, None, &[], connect)
            .expect("zenoh config");
        let mut set = |k: &str, v: String| c.insert_json5(k, &v).expect(k);
        set("listen/endpoints", "[]".into());
        if client {
            set("mode", "\"client\"".into());
        }
        let path = |p: &Path| serde_json::to_string(&p.display().to_string()).unwrap();
        if let Some(ca) = tls.ca {
            set("transport/link/tls/root_ca_certificate", path(ca));
        }
        match tls.identity {
            Some((cert, key)) => {
                set("transport/link/tls/enable_mtls", "true".into());
                set("transport/link/tls/connect_certificate", path(cert));
                set("transport/link/tls/connect_private_key", path(key));
            }
            None => set("transport/link/tls/enable_mtls", "false".into()),
        }
        let session = rt
            .block_on(async { zenoh::open(c).await })
            .map_err(|e| e.to_string())?;
        Ok(TestSession { rt, session })
    }

    /// Links (peers and routers) up after up to `wait` (the session keeps retrying).
    pub fn links_after(&self, want: usize, wait: Duration) -> usize {
        let t0 = Instant::now();
        loop {
            let n = self.rt.block_on(async {
                let info = self.session.info();
                info.peers_zid().await.count() + info.routers_zid().await.count()
            });
            if n >= want || t0.elapsed() > wait {
                return n;
            }
            std::thread::sleep(Duration::from_millis(100));
        }
    }

    /// Samples received on `key` within `d`: key and payload.
    pub fn samples(&self, key: &str, d: Duration) -> Vec<(String, Vec<u8>)> {
        self.samples_while(key, d, || {})
    }

    /// Samples received on `key` within `d`, calling `poke` every 100 ms meanwhile (to make
    /// something publish while this session listens).
    pub fn samples_while(
        &self,
        key: &str,
        d: Duration,
        mut poke: impl FnMut(),
    ) -> Vec<(String, Vec<u8>)> {
        let got = Arc::new(Mutex::new(Vec::new()));
        let sink = got.clone();
        let sub = self
            .rt
            .block_on(async {
                self.session
                    .declare_subscriber(key.to_string())
                    .callback(move |s| {
                        sink.lock().unwrap_or_else(|p| p.into_inner()).push((
                            s.key_expr().as_str().to_string(),
                            s.payload().to_bytes().to_vec(),
                        ))
                    })
                    .await
            })
            .expect("subscribe");
        let end = Instant::now() + d;
        while let Some(left) = end.checked_duration_since(Instant::now()) {
            poke();
            std::thread::sleep(Duration::from_millis(100).min(left));
        }
        drop(sub);
        let out = std::mem::take(&mut *got.lock().unwrap_or_else(|p| p.into_inner()));
        out
    }

    /// Puts `bytes` on `key`, blocking on congestion so that nothing is dropped locally.
    pub fn put(&self, key: &str, bytes: Vec<u8>) {
        self.rt.block_on(async {
            self.session
                .put(key.to_string(), bytes)
                .congestion_control(zenoh::qos::CongestionControl::Block)
                .await
                .expect("put")
        });
    }

    /// A fresh goal command to map point (`x`, `y`), stamped by this session.
    pub fn goal_bytes(&self, goal_id: u32, x: f64, y: f64) -> Vec<u8> {
        let st = CommandStamper::new(operator_station::station::sender_id(&self.session));
        let g = GoalCmd {
            goal_id,
            target: GoalTarget::Map { x_m: x, y_m: y },
            tolerance_m: 0.0,
        };
        msg::encode_cmd(st.next(unix_ms()), &g)
    }
}

impl Drop for TestSession {
    fn drop(&mut self) {
        let s = self.session.clone();
        let _ = self.rt.block_on(async { s.close().await });
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
