//! One robot's brain, as owned parts with narrow interfaces:
//!
//! - [`localiser`]: SLAM, GNSS anchoring and fusion, tilt from gravity, trust gates: sensor
//!   data in, a pose estimate with its frame out, and whether it may be mapped and taught.
//! - [`terrain`]: the traversability mapper and the planning grids, with their layers
//!   (footprint clearing, lasting-stop stamp, taught corridor) as pure functions.
//! - [`mission`]: one state machine (`Idle | Goal | Teleop | Teach | Repeat`) and the missions.
//! - [`driver`]: the path followers and the safety gate.
//! - [`zones`]: keep-out and slow zones: the planning layer, goal refusal, speed caps.
//! - [`Agent`]: the orchestrator over them; [`command`] and [`status`] are its own input and
//!   output types (the robot agent's bus translates them to and from the wire).
//!
//! No Zenoh, no tokio, no clock, no simulator: Cargo keeps them out. The runtime that feeds
//! the agent owns time and I/O, so a simulator, a real robot and a replay are the same to it.
#![deny(missing_docs)]

mod agent;
#[cfg(test)]
mod agent_tests;
pub mod command;
pub mod config;
pub mod driver;
pub mod localiser;
pub mod mission;
pub mod probe;
pub mod status;
pub mod terrain;
pub mod zones;

pub use agent::{Agent, Identity, ScanReport};
pub use command::{Command, CommandKind};
pub use config::{AgentConfig, MissionFile};
pub use driver::Cmd;
pub use localiser::PoseMap;
pub use probe::{NoProbe, Probe, Stage};
pub use status::{AgentStatus, PoseEstimate};
