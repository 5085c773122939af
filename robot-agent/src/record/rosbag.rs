//! ROS 2 bags as replay sources: `ros2 bag record` writes MCAP (CDR messages with `ros2msg`
//! schemas) or, before Iron, SQLite `.db3`. The topics the runtime knows become its inputs
//! through the same conversions as a live ROS 2 robot (`run::convert`): `PointCloud2` (LiDAR or
//! depth), `velodyne_msgs/VelodyneScan` packets (assembled into sweeps by the VLP-16 decoder),
//! `Odometry`, `Imu`, `NavSatFix`, a heading `QuaternionStamped`, and `/tf_static` for the frames.
//! Which topic feeds what follows the robot's `[io]` specs (`--lidar ros2:TOPIC`, ...); a LiDAR
//! topic the specs do not name is found by type when the bag has only one.

use super::replay::Event;
use crate::run::convert::{self, Frames};
use crate::runtime::stamps::Topic;
use crate::runtime::Input;
use io::cdr;
use io::ros2::keys;
use nalgebra::Isometry3;
use sensing::velodyne::rosbag::{decode_velodyne_scan, VELODYNE_SCAN_TYPE};
use sensing::velodyne::{ScanAssembler, VelodyneConfig};
use std::collections::{BTreeMap, HashMap, VecDeque};
use std::path::Path;

/// What a topic feeds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Role {
    /// LiDAR clouds (PointCloud2) or packets (VelodyneScan).
    Lidar,
    /// Depth-camera clouds.
    Depth,
    /// Odometry.
    Odom,
    /// IMU.
    Imu,
    /// NavSatFix.
    Fix,
    /// Heading.
    Heading,
    /// `tf_static`.
    TfStatic,
}

impl Role {
    fn stream(self) -> Option<Topic> {
        Some(match self {
            Role::Lidar => Topic::Lidar,
            Role::Depth => Topic::Depth,
            Role::Odom => Topic::Odom,
            Role::Imu => Topic::Imu,
            Role::Fix => Topic::Gnss,
            Role::Heading => Topic::Heading,
            Role::TfStatic => return None,
        })
    }
}

/// The topic names the robot's `[io]` specs give (relative or absolute); `None`: not configured.
#[derive(Clone, Debug, Default)]
pub struct BagTopics {
    /// LiDAR.
    pub lidar: Option<String>,
    /// Depth camera.
    pub depth: Option<String>,
    /// Odometry.
    pub odom: Option<String>,
    /// IMU.
    pub imu: Option<String>,
    /// GNSS fix.
    pub fix: Option<String>,
    /// Heading.
    pub heading: Option<String>,
}

fn same_topic(a: &str, b: &str) -> bool {
    a.trim_start_matches('/') == b.trim_start_matches('/')
}

/// Assigns roles to a bag's topics `(name, type)`.
pub fn assign(topics: &[(String, String)], want: &BagTopics) -> BTreeMap<String, Role> {
    let mut out = BTreeMap::new();
    const CLOUDS: &[&str] = &[keys::POINT_CLOUD2.name, VELODYNE_SCAN_TYPE];
    const CLOUD: &[&str] = &[keys::POINT_CLOUD2.name];
    const ODOM: &[&str] = &[keys::ODOMETRY.name];
    const IMU: &[&str] = &[keys::IMU.name];
    const FIX: &[&str] = &[keys::NAV_SAT_FIX.name];
    const HEADING: &[&str] = &[keys::QUATERNION_STAMPED.name];
    let named = [
        (&want.lidar, Role::Lidar, CLOUDS),
        (&want.depth, Role::Depth, CLOUD),
        (&want.odom, Role::Odom, ODOM),
        (&want.imu, Role::Imu, IMU),
        (&want.fix, Role::Fix, FIX),
        (&want.heading, Role::Heading, HEADING),
    ];
    for (name, role, types) in named {
        if let Some(n) = name {
            if let Some((t, _)) = topics
                .iter()
                .find(|(t, ty)| same_topic(t, n) && types.contains(&ty.as_str()))
            {
                out.insert(t.clone(), role);
            }
        }
    }
    if !out.values().any(|r| *r == Role::Lidar) {
        // A bag of another robot: its one LiDAR topic, whatever it is called.
        for ty in [VELODYNE_SCAN_TYPE, keys::POINT_CLOUD2.name] {
            let free: Vec<&String> = topics
                .iter()
                .filter(|(t, x)| x == ty && !out.contains_key(t))
                .map(|(t, _)| t)
                .collect();
            if let [one] = free[..] {
                out.insert(one.clone(), Role::Lidar);
                break;
            }
        }
    }
    for (t, ty) in topics {
        if ty == keys::TF_MESSAGE.name && same_topic(t, "tf_static") {
            out.insert(t.clone(), Role::TfStatic);
        }
    }
    out
}

/// Turns a bag's CDR messages into runtime events.
pub struct Decoder {
    roles: BTreeMap<String, Role>,
    frames: Frames,
    lidar_mount: Isometry3<f64>,
    depth_mount: Isometry3<f64>,
    velodyne: ScanAssembler,
    /// Sweeps left out because the bag ended before they were complete.
    pub partial_sweeps: u64,
}

impl Decoder {
    /// A decoder for topics with `roles`; mounts from the robot profile.
    pub fn new(
        roles: BTreeMap<String, Role>,
        lidar_mount: Isometry3<f64>,
        depth_mount: Isometry3<f64>,
    ) -> Self {
        Self {
            roles,
            frames: Frames::default(),
            lidar_mount,
            depth_mount,
            velodyne: ScanAssembler::new(VelodyneConfig::default()),
            partial_sweeps: 0,
        }
    }

    /// The runtime streams the bag feeds.
    pub fn streams(&self) -> Vec<Topic> {
        let mut v: Vec<Topic> = self.roles.values().filter_map(|r| r.stream()).collect();
        v.sort_by_key(|t| *t as usize);
        v.dedup();
        v
    }

    /// The roles.
    pub fn roles(&self) -> &BTreeMap<String, Role> {
        &self.roles
    }

    /// The events of one message on `topic` of type `ty`.
    pub fn decode(&mut self, topic: &str, ty: &str, data: &[u8], out: &mut VecDeque<Event>) {
        let Some(&role) = self.roles.get(topic) else {
            return;
        };
        let stream = role.stream().unwrap_or(Topic::Lidar);
        let bad = |e: String| Event::Undecodable(stream, format!("{topic}: {e}"));
        match (role, ty) {
            (Role::TfStatic, _) => match cdr::decode_tf_message(data) {
                Ok(tfs) => {
                    self.frames.add(&tfs);
                }
                Err(e) => tracing::warn!("{topic}: {e}"),
            },
            (Role::Lidar, t) if t == VELODYNE_SCAN_TYPE => match decode_velodyne_scan(data) {
                Ok(m) => {
                    for p in m.packets {
                        for s in self.velodyne.push_packet(&p.data, p.stamp_s) {
                            out.push_back(Event::Input(Input::Scan(s.to_scan())));
                        }
                    }
                }
                Err(e) => out.push_back(bad(e.to_string())),
            },
            (Role::Lidar | Role::Depth, _) => match cdr::decode_point_cloud2(data) {
                Ok(c) => {
                    let mount = if role == Role::Lidar {
                        self.lidar_mount
                    } else {
                        self.depth_mount
                    };
                    let s = convert::cloud_to_scan(&c, &self.frames, &mount);
                    out.push_back(Event::Input(if role == Role::Lidar {
                        Input::Scan(s)
                    } else {
                        Input::Depth(s)
                    }));
                }
                Err(e) => out.push_back(bad(e.to_string())),
            },
            (Role::Odom, _) => match cdr::decode_odometry(data) {
                Ok(o) => out.push_back(match convert::odometry(&o) {
                    Some(s) => Event::Input(Input::Odom(s)),
                    None => bad("odometry with a non-finite value".into()),
                }),
                Err(e) => out.push_back(bad(e.to_string())),
            },
            (Role::Imu, _) => match cdr::decode_imu(data) {
                Ok(m) => out.push_back(Event::Input(Input::Imu(convert::imu(&m, &self.frames)))),
                Err(e) => out.push_back(bad(e.to_string())),
            },
            (Role::Fix, _) => match cdr::decode_nav_sat_fix(data) {
                Ok(f) => out.push_back(Event::Input(Input::Fix(convert::fix(&f)))),
                Err(e) => out.push_back(bad(e.to_string())),
            },
            (Role::Heading, _) => match cdr::decode_heading_quaternion(data) {
                Ok(h) => out.push_back(Event::Input(Input::Heading(convert::heading(&h)))),
                Err(e) => out.push_back(bad(e.to_string())),
            },
        }
    }

    /// The bag ended: a sweep still being assembled is incomplete and left out (counted).
    pub fn finish(&mut self) {
        if self.velodyne.finish().is_some() {
            self.partial_sweeps += 1;
        }
    }
}

/// The messages of a rosbag2 SQLite file in time order: (topic, type, CDR bytes).
pub struct Db3 {
    conn: rusqlite::Connection,
    types: HashMap<i64, (String, String)>,
    ids: std::vec::IntoIter<(i64, i64)>,
}

impl Db3 {
    /// Opens `path` read-only; lists its topics.
    pub fn open(path: &Path) -> anyhow::Result<(Self, Vec<(String, String)>)> {
        let conn = rusqlite::Connection::open_with_flags(
            path,
            rusqlite::OpenFlags::SQLITE_OPEN_READ_ONLY | rusqlite::OpenFlags::SQLITE_OPEN_NO_MUTEX,
        )?;
        let mut types = HashMap::new();
        {
            let mut st = conn.prepare("SELECT id, name, type FROM topics ORDER BY id")?;
            let rows = st.query_map([], |r| {
                Ok((
                    r.get::<_, i64>(0)?,
                    r.get::<_, String>(1)?,
                    r.get::<_, String>(2)?,
                ))
            })?;
            for row in rows {
                let (id, name, ty) = row?;
                types.insert(id, (name, ty));
            }
        }
        let ids: Vec<(i64, i64)> = {
            let mut st =
                conn.prepare("SELECT id, topic_id FROM messages ORDER BY timestamp, id")?;
            let rows = st.query_map([], |r| Ok((r.get(0)?, r.get(1)?)))?;
            rows.collect::<Result<_, _>>()?
        };
        let mut topics: Vec<(String, String)> = types.values().cloned().collect();
        topics.sort();
        Ok((
            Self {
                conn,
                types,
                ids: ids.into_iter(),
            },
            topics,
        ))
    }

    /// The next message, `None` at the end.
    pub fn next_message(&mut self) -> Option<anyhow::Result<(String, String, Vec<u8>)>> {
        let (id, topic_id) = self.ids.next()?;
        let Some((name, ty)) = self.types.get(&topic_id).cloned() else {
            return Some(Err(anyhow::anyhow!(
                "message {id} of unknown topic {topic_id}"
            )));
        };
        Some(
            self.conn
                .query_row("SELECT data FROM messages WHERE id = ?1", [id], |r| {
                    r.get::<_, Vec<u8>>(0)
                })
                .map(|data| (name, ty, data))
                .map_err(anyhow::Error::from),
        )
    }
}

/// True when `path` is an SQLite file (a `.db3` bag).
pub fn is_sqlite(path: &Path) -> bool {
    use std::io::Read;
    let mut magic = [0u8; 16];
    std::fs::File::open(path)
        .and_then(|mut f| f.read_exact(&mut magic))
        .is_ok()
        && &magic == b"SQLite format 3\0"
}
