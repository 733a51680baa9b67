//! Recordings: rosbag2 bags (a directory with `metadata.yaml` and MCAP or SQLite3 storage, or a
//! lone `.mcap` / `.db3` file) of CDR-encoded ROS 2 messages.
//!
//! - `write`: pegs's own recordings (rosbag2 directories with MCAP storage) and message builders.
//! - `read`: any such bag streamed message by message (`BagReader`), bounded in memory.
//! - `metadata`, `sqlite`: rosbag2's `metadata.yaml` and SQLite3 storage.
//! - `tf`: the tf tree, resolving a camera's optical frame through chains of transforms.

mod metadata;
mod read;
mod sqlite;
mod tf;
mod write;

pub use read::{BagReader, RawMessage, read_messages};
pub use tf::TfTree;
pub use write::*;
