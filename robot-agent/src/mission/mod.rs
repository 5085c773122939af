//! Missions: go to a goal (map or GNSS), teach (record a route) and repeat (follow it back).

pub mod gnss;
pub mod navigate;
pub mod repeat;
pub mod teach;
