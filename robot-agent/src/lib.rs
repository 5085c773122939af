//! terranav robot agent: the runtime around the robot's brain ([`agent`], its own crate): the
//! configuration files, the Zenoh bus, the built-in simulator as a robot, and the tools.
//!
//! The algorithms and the agent's parts are separate crates under `robot-agent/` (re-exported
//! here) so they cannot reach Zenoh, tokio or the clock; [`bus`] is the only module that touches
//! the network.
#![deny(missing_docs)]

pub use agent;
pub use control;
pub use mapping;
pub use planning;
pub use sensing;
pub use sim;
pub use slam;

pub mod bus;
pub mod cli;
pub mod config;
pub mod navcomp;
pub mod record;
pub mod run;
pub mod runtime;
pub mod truth_log;
