//! Missions: go to a goal (map or GNSS), teach (record a route) and repeat (follow it back),
//! and the Orpheus navigation-computer gateway's logic.

pub mod gnss;
pub mod gnss_tilt;
pub mod navigate;
pub mod orpheus;
pub mod repeat;
pub mod teach;
pub mod teach_view;
