//! Source and sink specs as the command line and the `[io]` config section write them:
//!
//! | spec | what |
//! | --- | --- |
//! | `ros2:TOPIC` | a ROS 2 topic over Zenoh (key form and namespace set elsewhere) |
//! | `vlp16-udp:PORT` | Velodyne VLP-16 data packets on a UDP port |
//! | `nmea-serial:DEVICE@BAUD` | NMEA from a serial port, e.g. `nmea-serial:/dev/ttyACM0@115200` |
//! | `nmea-tcp:HOST:PORT` | NMEA from a TCP server |
//! | `nmea-udp:PORT` | NMEA datagrams on a UDP port |
//! | `gpsd:HOST:PORT` | gpsd's JSON reports (port 2947 by default: `gpsd:HOST`) |
//! | `orpheus-udp:HOST:PORT` | a navigation computer speaking the Orpheus waypoint protocol (a sink) |
//! | `sim` | the built-in simulator |

use std::fmt;

/// Why a spec was refused.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("source {spec:?}: {why} (expected one of ros2:TOPIC, vlp16-udp:PORT, nmea-serial:DEVICE@BAUD, nmea-tcp:HOST:PORT, nmea-udp:PORT, gpsd:HOST[:PORT], orpheus-udp:HOST:PORT, sim)")]
pub struct SpecError {
    /// The spec as given.
    pub spec: String,
    /// What is wrong with it.
    pub why: String,
}

/// gpsd's registered port.
pub const GPSD_PORT: u16 = 2947;

/// A parsed source (or sink) spec.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum SourceSpec {
    /// A ROS 2 topic.
    Ros2 {
        /// Topic name, relative (`velodyne_points`) or absolute (`/velodyne_points`).
        topic: String,
    },
    /// VLP-16 packets on UDP.
    Vlp16Udp {
        /// Port (2368 is the Velodyne default).
        port: u16,
    },
    /// NMEA on a serial port.
    NmeaSerial {
        /// Device path.
        device: String,
        /// Baud rate.
        baud: u32,
    },
    /// NMEA over TCP.
    NmeaTcp {
        /// Host.
        host: String,
        /// Port.
        port: u16,
    },
    /// NMEA over UDP.
    NmeaUdp {
        /// Port to listen on.
        port: u16,
    },
    /// gpsd.
    Gpsd {
        /// Host.
        host: String,
        /// Port.
        port: u16,
    },
    /// A navigation computer that follows waypoint lists (Orpheus protocol over UDP).
    OrpheusUdp {
        /// Its host.
        host: String,
        /// Its port.
        port: u16,
    },
    /// The simulator.
    Sim,
}

fn port(s: &str, what: &str) -> Result<u16, String> {
    match s.parse::<u16>() {
        Ok(p) if p > 0 => Ok(p),
        _ => Err(format!("{what} {s:?} is not a port number 1-65535")),
    }
}

/// `HOST:PORT`, with `[v6]:PORT` for IPv6 literals.
fn host_port(s: &str, default_port: Option<u16>) -> Result<(String, u16), String> {
    let (host, p) = if let Some(rest) = s.strip_prefix('[') {
        let (h, tail) = rest.split_once(']').ok_or("unclosed '[' in host")?;
        (h, tail.strip_prefix(':'))
    } else {
        match s.rsplit_once(':') {
            Some((h, p)) => (h, Some(p)),
            None => (s, None),
        }
    };
    if host.is_empty() {
        return Err("empty host".into());
    }
    let p = match (p, default_port) {
        (Some(p), _) => port(p, "port")?,
        (None, Some(d)) => d,
        (None, None) => return Err("missing :PORT".into()),
    };
    Ok((host.to_owned(), p))
}

impl SourceSpec {
    /// Parses a spec.
    pub fn parse(spec: &str) -> Result<Self, SpecError> {
        let err = |why: String| SpecError {
            spec: spec.to_owned(),
            why,
        };
        let s = spec.trim();
        if s == "sim" {
            return Ok(SourceSpec::Sim);
        }
        let (kind, rest) = s
            .split_once(':')
            .ok_or_else(|| err("no KIND: prefix".into()))?;
        match kind {
            "ros2" => {
                let topic = rest.trim();
                let bad = topic.trim_matches('/').is_empty()
                    || topic.contains("//")
                    || !topic
                        .chars()
                        .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '/' || c == '~');
                if bad {
                    return Err(err(format!("{topic:?} is not a ROS 2 topic name")));
                }
                Ok(SourceSpec::Ros2 {
                    topic: topic.to_owned(),
                })
            }
            "vlp16-udp" => Ok(SourceSpec::Vlp16Udp {
                port: port(rest, "port").map_err(err)?,
            }),
            "nmea-udp" => Ok(SourceSpec::NmeaUdp {
                port: port(rest, "port").map_err(err)?,
            }),
            "nmea-tcp" => {
                let (host, port) = host_port(rest, None).map_err(err)?;
                Ok(SourceSpec::NmeaTcp { host, port })
            }
            "gpsd" => {
                let (host, port) = host_port(rest, Some(GPSD_PORT)).map_err(err)?;
                Ok(SourceSpec::Gpsd { host, port })
            }
            "orpheus-udp" => {
                let (host, port) = host_port(rest, None).map_err(err)?;
                Ok(SourceSpec::OrpheusUdp { host, port })
            }
            "nmea-serial" => {
                let (device, baud) = rest
                    .rsplit_once('@')
                    .ok_or_else(|| err("missing @BAUD".into()))?;
                if device.is_empty() {
                    return Err(err("empty device".into()));
                }
                let baud = match baud.parse::<u32>() {
                    Ok(b) if (300..=4_000_000).contains(&b) => b,
                    _ => return Err(err(format!("baud {baud:?} is not 300-4000000"))),
                };
                Ok(SourceSpec::NmeaSerial {
                    device: device.to_owned(),
                    baud,
                })
            }
            other => Err(err(format!("unknown kind {other:?}"))),
        }
    }

    /// Whether this spec can deliver GNSS (NMEA, gpsd, a NavSatFix topic, the simulator).
    pub fn is_gnss(&self) -> bool {
        !matches!(
            self,
            SourceSpec::Vlp16Udp { .. } | SourceSpec::OrpheusUdp { .. }
        )
    }
}

impl std::str::FromStr for SourceSpec {
    type Err = SpecError;
    fn from_str(s: &str) -> Result<Self, SpecError> {
        SourceSpec::parse(s)
    }
}

impl fmt::Display for SourceSpec {
    /// The spec as it parses back.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let hp = |h: &str| {
            if h.contains(':') {
                format!("[{h}]")
            } else {
                h.to_owned()
            }
        };
        match self {
            SourceSpec::Ros2 { topic } => write!(f, "ros2:{topic}"),
            SourceSpec::Vlp16Udp { port } => write!(f, "vlp16-udp:{port}"),
            SourceSpec::NmeaSerial { device, baud } => write!(f, "nmea-serial:{device}@{baud}"),
            SourceSpec::NmeaTcp { host, port } => write!(f, "nmea-tcp:{}:{port}", hp(host)),
            SourceSpec::NmeaUdp { port } => write!(f, "nmea-udp:{port}"),
            SourceSpec::Gpsd { host, port } => write!(f, "gpsd:{}:{port}", hp(host)),
            SourceSpec::OrpheusUdp { host, port } => write!(f, "orpheus-udp:{}:{port}", hp(host)),
            SourceSpec::Sim => write!(f, "sim"),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_every_kind_and_round_trips() {
        let cases = [
            (
                "ros2:velodyne_points",
                SourceSpec::Ros2 {
                    topic: "velodyne_points".into(),
                },
            ),
            (
                "ros2:/imu/data",
                SourceSpec::Ros2 {
                    topic: "/imu/data".into(),
                },
            ),
            ("vlp16-udp:2368", SourceSpec::Vlp16Udp { port: 2368 }),
            (
                "nmea-serial:/dev/ttyACM0@115200",
                SourceSpec::NmeaSerial {
                    device: "/dev/ttyACM0".into(),
                    baud: 115200,
                },
            ),
            (
                "nmea-tcp:192.168.1.5:5017",
                SourceSpec::NmeaTcp {
                    host: "192.168.1.5".into(),
                    port: 5017,
                },
            ),
            (
                "nmea-tcp:[::1]:5017",
                SourceSpec::NmeaTcp {
                    host: "::1".into(),
                    port: 5017,
                },
            ),
            ("nmea-udp:10110", SourceSpec::NmeaUdp { port: 10110 }),
            (
                "gpsd:localhost:2947",
                SourceSpec::Gpsd {
                    host: "localhost".into(),
                    port: 2947,
                },
            ),
            (
                "orpheus-udp:192.168.1.20:10110",
                SourceSpec::OrpheusUdp {
                    host: "192.168.1.20".into(),
                    port: 10110,
                },
            ),
            ("sim", SourceSpec::Sim),
        ];
        for (text, want) in cases {
            let got = SourceSpec::parse(text).unwrap();
            assert_eq!(got, want, "{text}");
            assert_eq!(SourceSpec::parse(&got.to_string()).unwrap(), want);
        }
        assert_eq!(
            SourceSpec::parse("gpsd:robot").unwrap(),
            SourceSpec::Gpsd {
                host: "robot".into(),
                port: 2947
            }
        );
    }

    #[test]
    fn clear_errors() {
        for (bad, says) in [
            ("", "no KIND"),
            ("velodyne", "no KIND"),
            ("ros3:x", "unknown kind"),
            ("ros2:", "not a ROS 2 topic"),
            ("ros2:a b", "not a ROS 2 topic"),
            ("vlp16-udp:0", "not a port"),
            ("vlp16-udp:99999", "not a port"),
            ("nmea-tcp:host", "missing :PORT"),
            ("nmea-tcp::5", "empty host"),
            ("nmea-serial:/dev/ttyUSB0", "missing @BAUD"),
            ("nmea-serial:/dev/ttyUSB0@fast", "baud"),
        ] {
            let e = SourceSpec::parse(bad).unwrap_err().to_string();
            assert!(e.contains(says), "{bad:?}: {e}");
        }
    }
}
