//! Command-line front ends, one module per subcommand group. Each prints machine-readable output
//! (one JSON object per line, or the documented summary line) on stdout and logs on stderr.

pub mod bench;
pub mod geo;
pub mod gnss;
pub mod lidar;
pub mod map;
pub mod mission;
pub mod plan;
pub mod run;
pub mod sim;
pub mod slam;
