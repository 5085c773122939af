//! terranav sessions as MCAP (what `ros2 bag` writes by default and Foxglove and Lichtblick open).
//!
//! - [`schemas`]: the message schemas, Foxglove's own (vendored from `@foxglove/schemas`) where one
//!   fits and terranav's where none does, all JSON Schema with JSON messages.
//! - [`foxglove`]: builders of those messages from terranav's types (tiles as grids, poses,
//!   paths and goals as scene entities).
//! - [`writer`]: the recorder thread behind a bounded queue: chunked, compressed, indexed, rotated.
//! - [`reader`]: reads a file front to back, a cut one up to its last closed chunk.
//!
//! Why JSON messages rather than protobuf: a message is then a document that validates against
//! Foxglove's published JSON Schema as it stands (what the tests do), needs no generated code or
//! descriptor sets, and reads in any tool; floats are written in their shortest exact form, so a
//! replay reads back the very numbers the robot saw. What it costs is base64 for the bulk bytes
//! (clouds, grids), a third more before compression; the chunks are zstd-compressed.

pub mod foxglove;
pub mod reader;
pub mod schemas;
pub mod writer;

pub use reader::{Item, Message, ReadError, Reader};
pub use schemas::Schema;
pub use writer::{ChannelId, Finished, Options, Recorder, Split, Stats};

/// The MCAP header's profile of a terranav recording.
pub const PROFILE: &str = "terranav";

/// Name of the metadata record that describes the session (robot, identity, clock, config).
pub const SESSION_METADATA: &str = "terranav.session";
