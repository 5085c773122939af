//! terranav robot agent: wires sensing, SLAM, mapping, planning and control into missions, and
//! connects the robot to operator stations over Zenoh.
//!
//! The algorithms are separate crates under `robot-agent/` (re-exported here) so they cannot
//! reach Zenoh, tokio or the clock; [`bus`] is the only module that touches the network.
#![deny(missing_docs)]

pub use control;
pub use mapping;
pub use planning;
pub use sensing;
pub use sim;
pub use slam;

pub mod agent;
pub mod bus;
pub mod cli;
pub mod mission;
pub mod run;
