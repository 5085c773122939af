//! Zenoh key expressions of the terranav key space (see `docs/architecture.md`).
//!
//! Keys are only ever built and parsed here, so a typo cannot split the key space.

use std::fmt;

/// First chunk of every terranav key.
pub const PREFIX: &str = "terranav";

/// Longest accepted robot id, in bytes.
pub const MAX_ROBOT_ID_LEN: usize = 64;

/// A validated robot id: `[a-z0-9-]+`, at most [`MAX_ROBOT_ID_LEN`] bytes, not starting or ending with `-`.
#[derive(
    Clone, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, serde::Serialize, serde::Deserialize,
)]
#[serde(try_from = "String", into = "String")]
pub struct RobotId(String);

/// Why a robot id or key was refused.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum KeyError {
    /// The robot id is empty, too long or has characters outside `[a-z0-9-]`.
    #[error(
        "invalid robot id {0:?}: use 1-64 characters of [a-z0-9-], not starting or ending with '-'"
    )]
    InvalidRobotId(String),
    /// The key is not under `terranav/`.
    #[error("key {0:?} is not in the terranav key space")]
    NotTerranav(String),
    /// The key is under `terranav/<robot>/` but names no known topic.
    #[error("unknown topic in key {0:?}")]
    UnknownTopic(String),
    /// A tile key whose indices are not integers.
    #[error("bad tile index in key {0:?}")]
    BadTileIndex(String),
}

impl RobotId {
    /// Validates `id` as a robot id.
    pub fn new(id: impl Into<String>) -> Result<Self, KeyError> {
        let id = id.into();
        let ok = !id.is_empty()
            && id.len() <= MAX_ROBOT_ID_LEN
            && !id.starts_with('-')
            && !id.ends_with('-')
            && id
                .bytes()
                .all(|b| b.is_ascii_lowercase() || b.is_ascii_digit() || b == b'-');
        if ok {
            Ok(Self(id))
        } else {
            Err(KeyError::InvalidRobotId(id))
        }
    }

    /// The id as text.
    pub fn as_str(&self) -> &str {
        &self.0
    }
}

impl fmt::Display for RobotId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.0)
    }
}

impl TryFrom<String> for RobotId {
    type Error = KeyError;
    fn try_from(s: String) -> Result<Self, KeyError> {
        Self::new(s)
    }
}

impl From<RobotId> for String {
    fn from(r: RobotId) -> String {
        r.0
    }
}

impl std::str::FromStr for RobotId {
    type Err = KeyError;
    fn from_str(s: &str) -> Result<Self, KeyError> {
        Self::new(s)
    }
}

/// One topic under `terranav/<robot>/`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[non_exhaustive]
pub enum Topic {
    /// Liveliness token.
    Alive,
    /// Session announcement (pub + queryable).
    Session,
    /// Robot pose in the map frame.
    Pose,
    /// One traversability tile at lattice index (tx, ty) (pub + queryable).
    Tile {
        /// Tile column index on the map-frame lattice.
        tx: i32,
        /// Tile row index on the map-frame lattice.
        ty: i32,
    },
    /// Planned path.
    Path,
    /// Mission and health status.
    Status,
    /// A recorded route, published when a teach recording ends (pub + queryable).
    Route,
    /// The zones the robot must obey, in its map frame: published by the station, which also
    /// answers queries for it (a robot that starts late asks).
    Zones,
    /// Goal command.
    CmdGoal,
    /// Route command: record / stop / repeat / upload / pause / resume / cancel.
    CmdRoute,
    /// Teleop drive command.
    CmdDrive,
    /// Stop now.
    CmdStop,
    /// Speed limit command.
    CmdSpeed,
}

impl Topic {
    fn suffix(&self) -> String {
        match self {
            Topic::Alive => "alive".into(),
            Topic::Session => "session".into(),
            Topic::Pose => "pose".into(),
            Topic::Tile { tx, ty } => format!("tile/{tx}/{ty}"),
            Topic::Path => "path".into(),
            Topic::Status => "status".into(),
            Topic::Route => "route".into(),
            Topic::Zones => "zones".into(),
            Topic::CmdGoal => "cmd/goal".into(),
            Topic::CmdRoute => "cmd/route".into(),
            Topic::CmdDrive => "cmd/drive".into(),
            Topic::CmdStop => "cmd/stop".into(),
            Topic::CmdSpeed => "cmd/speed".into(),
        }
    }

    /// True for the `cmd/*` topics a robot subscribes to.
    pub fn is_command(&self) -> bool {
        matches!(
            self,
            Topic::CmdGoal | Topic::CmdRoute | Topic::CmdDrive | Topic::CmdStop | Topic::CmdSpeed
        )
    }
}

/// The key of `topic` for `robot`, e.g. `terranav/husky-1/tile/-3/7`.
pub fn key(robot: &RobotId, topic: Topic) -> String {
    format!("{PREFIX}/{robot}/{}", topic.suffix())
}

/// Every key of every robot: `terranav/**`.
pub fn all() -> String {
    format!("{PREFIX}/**")
}

/// Every key of one robot: `terranav/<robot>/**`.
pub fn robot_all(robot: &RobotId) -> String {
    format!("{PREFIX}/{robot}/**")
}

/// Every tile of one robot: `terranav/<robot>/tile/**`.
pub fn robot_tiles(robot: &RobotId) -> String {
    format!("{PREFIX}/{robot}/tile/**")
}

/// Liveliness tokens of every robot: `terranav/*/alive`.
pub fn all_alive() -> String {
    format!("{PREFIX}/*/alive")
}

/// Every robot's commands of one kind, e.g. all goal commands: `terranav/*/cmd/goal`.
pub fn robot_commands(robot: &RobotId) -> String {
    format!("{PREFIX}/{robot}/cmd/**")
}

/// The zone sets of every robot: `terranav/*/zones` (the station's queryable).
pub fn all_zones() -> String {
    format!("{PREFIX}/*/zones")
}

/// Parses a concrete key into its robot id and topic.
pub fn parse(key: &str) -> Result<(RobotId, Topic), KeyError> {
    let mut parts = key.split('/');
    if parts.next() != Some(PREFIX) {
        return Err(KeyError::NotTerranav(key.to_string()));
    }
    let robot = RobotId::new(parts.next().unwrap_or_default())?;
    let rest: Vec<&str> = parts.collect();
    let topic = match rest.as_slice() {
        ["alive"] => Topic::Alive,
        ["session"] => Topic::Session,
        ["pose"] => Topic::Pose,
        ["path"] => Topic::Path,
        ["status"] => Topic::Status,
        ["route"] => Topic::Route,
        ["zones"] => Topic::Zones,
        ["cmd", "goal"] => Topic::CmdGoal,
        ["cmd", "route"] => Topic::CmdRoute,
        ["cmd", "drive"] => Topic::CmdDrive,
        ["cmd", "stop"] => Topic::CmdStop,
        ["cmd", "speed"] => Topic::CmdSpeed,
        ["tile", tx, ty] => {
            let bad = || KeyError::BadTileIndex(key.to_string());
            Topic::Tile {
                tx: tx.parse().map_err(|_| bad())?,
                ty: ty.parse().map_err(|_| bad())?,
            }
        }
        _ => return Err(KeyError::UnknownTopic(key.to_string())),
    };
    Ok((robot, topic))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn robot_ids_are_validated() {
        for ok in ["husky-1", "a", "r2d2", "x-y-z"] {
            assert!(RobotId::new(ok).is_ok(), "{ok}");
        }
        for bad in [
            "",
            "Husky",
            "a/b",
            "a b",
            "-a",
            "a-",
            "*",
            "a**",
            "é",
            &"a".repeat(65),
        ] {
            assert!(RobotId::new(bad).is_err(), "{bad:?}");
        }
    }

    #[test]
    fn every_topic_round_trips() {
        let r = RobotId::new("husky-1").unwrap();
        let topics = [
            Topic::Alive,
            Topic::Session,
            Topic::Pose,
            Topic::Tile { tx: -3, ty: 7 },
            Topic::Path,
            Topic::Status,
            Topic::Route,
            Topic::Zones,
            Topic::CmdGoal,
            Topic::CmdRoute,
            Topic::CmdDrive,
            Topic::CmdStop,
            Topic::CmdSpeed,
        ];
        for t in topics {
            let k = key(&r, t);
            assert_eq!(parse(&k).unwrap(), (r.clone(), t), "{k}");
        }
        assert_eq!(
            key(&r, Topic::Tile { tx: -3, ty: 7 }),
            "terranav/husky-1/tile/-3/7"
        );
    }

    #[test]
    fn bad_keys_are_refused() {
        assert!(matches!(
            parse("other/x/pose"),
            Err(KeyError::NotTerranav(_))
        ));
        assert!(matches!(
            parse("terranav/X/pose"),
            Err(KeyError::InvalidRobotId(_))
        ));
        assert!(matches!(
            parse("terranav/x/nope"),
            Err(KeyError::UnknownTopic(_))
        ));
        assert!(matches!(
            parse("terranav/x/tile/1/a"),
            Err(KeyError::BadTileIndex(_))
        ));
        assert!(matches!(
            parse("terranav/x/tile/1"),
            Err(KeyError::UnknownTopic(_))
        ));
        assert!(matches!(
            parse("terranav"),
            Err(KeyError::InvalidRobotId(_))
        ));
    }

    #[test]
    fn robot_id_deserialisation_validates() {
        let bytes = postcard::to_allocvec(&"Not Valid".to_string()).unwrap();
        assert!(postcard::from_bytes::<RobotId>(&bytes).is_err());
    }
}
