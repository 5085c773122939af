//! GNSS drivers for `robot-agent run`: NMEA lines from a serial port, TCP or UDP, and gpsd's
//! JSON reports. Every message is stamped with the host's receive time: NMEA carries only the
//! time of day, and a receiver's (or a replayed log's) clock is not the robot's.

use super::convert;
use super::robot::{SourceEvent, SourceStart};
use crate::runtime::stamps::Topic;
use crate::runtime::Input;
use io::gnss::{unix_now_s, GnssEvent, GpsdClient, LineSource};
use io::source::SourceSpec;
use sensing::GnssSentence;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::Sender;
use std::sync::Arc;
use std::time::Duration;

/// Wait between reconnection attempts of a TCP or gpsd source, seconds.
const RECONNECT_S: f64 = 1.0;

/// The driver for a GNSS spec (`nmea-serial`, `nmea-tcp`, `nmea-udp`, `gpsd`); `None` for other
/// kinds.
pub fn source(spec: &SourceSpec) -> Option<SourceStart> {
    let spec = spec.clone();
    match &spec {
        SourceSpec::NmeaSerial { .. }
        | SourceSpec::NmeaTcp { .. }
        | SourceSpec::NmeaUdp { .. }
        | SourceSpec::Gpsd { .. } => {}
        _ => return None,
    }
    Some(Box::new(move |tx, stop| {
        let rt = match tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
        {
            Ok(rt) => rt,
            Err(e) => {
                let _ = tx.send(SourceEvent::Ended(Topic::Gnss, e.to_string()));
                return;
            }
        };
        rt.block_on(drive(spec, tx, stop));
    }))
}

async fn drive(spec: SourceSpec, tx: Sender<SourceEvent>, stop: Arc<AtomicBool>) {
    let mut warned = false;
    while !stop.load(Ordering::Relaxed) {
        let r = match &spec {
            SourceSpec::Gpsd { host, port } => match GpsdClient::connect(host, *port).await {
                Ok(c) => {
                    tracing::info!("gnss <- gpsd {host}:{port}");
                    warned = false;
                    gpsd_loop(c, &tx, &stop).await
                }
                Err(e) => Err(e),
            },
            SourceSpec::NmeaTcp { host, port } => match LineSource::tcp(host, *port).await {
                Ok(l) => {
                    tracing::info!("gnss <- NMEA tcp {host}:{port}");
                    warned = false;
                    nmea_loop(l, &tx, &stop).await
                }
                Err(e) => Err(e),
            },
            SourceSpec::NmeaUdp { port } => match LineSource::udp(*port).await {
                Ok(l) => {
                    tracing::info!("gnss <- NMEA udp :{port}");
                    nmea_loop(l, &tx, &stop).await
                }
                Err(e) => {
                    let _ = tx.send(SourceEvent::Ended(Topic::Gnss, format!("udp {port}: {e}")));
                    return;
                }
            },
            SourceSpec::NmeaSerial { device, baud } => match LineSource::serial(device, *baud) {
                Ok(l) => {
                    tracing::info!("gnss <- NMEA {device}@{baud}");
                    warned = false;
                    nmea_loop(l, &tx, &stop).await
                }
                Err(e) => Err(e),
            },
            _ => return,
        };
        match r {
            Ok(false) => return,
            Ok(true) => tracing::warn!("gnss source {spec} ended; reconnecting"),
            Err(e) if !warned => {
                tracing::warn!("gnss source {spec}: {e}; retrying every {RECONNECT_S} s");
                warned = true;
            }
            Err(_) => {}
        }
        tokio::time::sleep(Duration::from_secs_f64(RECONNECT_S)).await;
    }
}

/// Lines until the stream ends (`Ok(true)`: reconnect) or the loop stops (`Ok(false)`).
async fn nmea_loop(
    mut lines: LineSource,
    tx: &Sender<SourceEvent>,
    stop: &AtomicBool,
) -> std::io::Result<bool> {
    while !stop.load(Ordering::Relaxed) {
        let line = match tokio::time::timeout(Duration::from_millis(200), lines.next_line()).await {
            Err(_) => continue,
            Ok(r) => r?,
        };
        let Some(text) = line else { return Ok(true) };
        if text.trim().is_empty() {
            continue;
        }
        let input = Input::Gnss(GnssSentence {
            t_s: unix_now_s(),
            text,
        });
        if tx.send(SourceEvent::Input(input)).is_err() {
            return Ok(false);
        }
    }
    Ok(false)
}

async fn gpsd_loop(
    mut client: GpsdClient,
    tx: &Sender<SourceEvent>,
    stop: &AtomicBool,
) -> std::io::Result<bool> {
    let mut refused = 0;
    while !stop.load(Ordering::Relaxed) {
        let ev = match tokio::time::timeout(Duration::from_millis(200), client.next()).await {
            Err(_) => continue,
            Ok(r) => r?,
        };
        for _ in refused..client.refused {
            let why = client
                .last_error
                .as_ref()
                .map_or_else(|| "refused".to_string(), ToString::to_string);
            let _ = tx.send(SourceEvent::Undecodable(
                Topic::Gnss,
                format!("gpsd: {why}"),
            ));
        }
        refused = client.refused;
        let Some(ev) = ev else { return Ok(true) };
        let now = unix_now_s();
        let input = match ev {
            GnssEvent::Fix(mut f) => {
                f.stamp_s = now;
                Input::Fix(convert::fix(&f))
            }
            GnssEvent::Heading(mut h) => {
                h.stamp_s = now;
                Input::Heading(convert::heading(&h))
            }
        };
        if tx.send(SourceEvent::Input(input)).is_err() {
            return Ok(false);
        }
    }
    Ok(false)
}
