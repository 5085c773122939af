//! The schemas of a recording. Foxglove's are copied unchanged from the npm package
//! `@foxglove/schemas` 2.1.0 (MIT; `record/schemas/foxglove/`, checked against the package by
//! `tests/record.rs`); Foxglove and Lichtblick recognise them by name and draw them. terranav's
//! own (`record/schemas/terranav/`) cover what has no Foxglove schema: IMU samples, NMEA sentences,
//! headings, commands, status, the session and tiles as sent to the station.

/// A schema as an MCAP file stores it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Schema {
    /// Name (`foxglove.PointCloud`).
    pub name: String,
    /// Schema encoding (`jsonschema`, `ros2msg`).
    pub encoding: String,
    /// The schema's text.
    pub data: String,
}

impl Schema {
    /// A JSON Schema.
    pub fn json(name: &str, data: &str) -> Self {
        Self {
            name: name.into(),
            encoding: "jsonschema".into(),
            data: data.into(),
        }
    }

    /// A ROS 2 message definition (for CDR channels).
    pub fn ros2msg(name: &str, data: &str) -> Self {
        Self {
            name: name.into(),
            encoding: "ros2msg".into(),
            data: data.into(),
        }
    }
}

macro_rules! schemas {
    ($($(#[$doc:meta])* $f:ident = $name:literal, $file:literal;)*) => {
        $(
            $(#[$doc])*
            pub fn $f() -> Schema {
                Schema::json($name, include_str!($file))
            }
        )*
    };
}

/// Foxglove's schemas.
pub mod foxglove {
    use super::Schema;
    schemas! {
        /// `foxglove.PointCloud`.
        point_cloud = "foxglove.PointCloud", "../schemas/foxglove/PointCloud.json";
        /// `foxglove.Odometry`.
        odometry = "foxglove.Odometry", "../schemas/foxglove/Odometry.json";
        /// `foxglove.LocationFix`.
        location_fix = "foxglove.LocationFix", "../schemas/foxglove/LocationFix.json";
        /// `foxglove.FrameTransform`.
        frame_transform = "foxglove.FrameTransform", "../schemas/foxglove/FrameTransform.json";
        /// `foxglove.FrameTransforms`.
        frame_transforms = "foxglove.FrameTransforms", "../schemas/foxglove/FrameTransforms.json";
        /// `foxglove.PoseInFrame`.
        pose_in_frame = "foxglove.PoseInFrame", "../schemas/foxglove/PoseInFrame.json";
        /// `foxglove.Grid`.
        grid = "foxglove.Grid", "../schemas/foxglove/Grid.json";
        /// `foxglove.SceneUpdate`.
        scene_update = "foxglove.SceneUpdate", "../schemas/foxglove/SceneUpdate.json";
        /// `foxglove.Log`.
        log = "foxglove.Log", "../schemas/foxglove/Log.json";
    }
}

/// terranav's schemas.
pub mod terranav {
    use super::Schema;
    schemas! {
        /// `terranav.Imu`.
        imu = "terranav.Imu", "../schemas/terranav/Imu.json";
        /// `terranav.NmeaSentence`.
        nmea_sentence = "terranav.NmeaSentence", "../schemas/terranav/NmeaSentence.json";
        /// `terranav.Heading`.
        heading = "terranav.Heading", "../schemas/terranav/Heading.json";
        /// `terranav.Command`.
        command = "terranav.Command", "../schemas/terranav/Command.json";
        /// `terranav.BaseCommand`.
        base_command = "terranav.BaseCommand", "../schemas/terranav/BaseCommand.json";
        /// `terranav.Status`.
        status = "terranav.Status", "../schemas/terranav/Status.json";
        /// `terranav.Session`.
        session = "terranav.Session", "../schemas/terranav/Session.json";
        /// `terranav.Tile`.
        tile = "terranav.Tile", "../schemas/terranav/Tile.json";
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn every_schema_is_json_with_its_own_title() {
        for s in [
            super::foxglove::point_cloud(),
            super::foxglove::odometry(),
            super::foxglove::location_fix(),
            super::foxglove::frame_transform(),
            super::foxglove::frame_transforms(),
            super::foxglove::pose_in_frame(),
            super::foxglove::grid(),
            super::foxglove::scene_update(),
            super::foxglove::log(),
            super::terranav::imu(),
            super::terranav::nmea_sentence(),
            super::terranav::heading(),
            super::terranav::command(),
            super::terranav::base_command(),
            super::terranav::status(),
            super::terranav::session(),
            super::terranav::tile(),
        ] {
            let v: serde_json::Value = serde_json::from_str(&s.data).unwrap();
            assert_eq!(v["title"], s.name.as_str());
        }
    }
}
