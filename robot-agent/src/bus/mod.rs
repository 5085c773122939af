//! The only place that touches Zenoh: publishes session, pose, tiles, path and status; answers
//! queries; receives and validates commands.
pub mod orpheus;
