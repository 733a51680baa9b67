//! rosbag2's `metadata.yaml`: read to find a bag's storage files in order, written beside pegs's
//! own MCAP storage so its recordings are rosbag2 directories that `ros2 bag info/play` accept.
//! Owns the file format only; opening the storage files is `read`'s job.

use anyhow::{Context, Result, bail};
use serde::Deserialize;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// The part of a rosbag2 `metadata.yaml` that says where the messages are.
#[derive(Deserialize)]
struct BagMetadata {
    rosbag2_bagfile_information: BagInformation,
}

#[derive(Deserialize)]
struct BagInformation {
    storage_identifier: String,
    relative_file_paths: Vec<String>,
    #[serde(default)]
    compression_format: String,
}

/// A rosbag2 directory's storage plugin and files in order.
pub struct BagFiles {
    pub storage: String,
    pub files: Vec<PathBuf>,
}

/// The storage files of the rosbag2 directory `dir`, in order; an error names what is missing
/// or not supported.
pub fn bag_files(dir: &Path) -> Result<BagFiles> {
    let meta_path = dir.join("metadata.yaml");
    let text = std::fs::read_to_string(&meta_path).with_context(|| {
        format!(
            "{} is a directory without metadata.yaml: not a rosbag2 bag (give an .mcap or .db3 \
             file or a rosbag2 directory)",
            dir.display()
        )
    })?;
    let meta: BagMetadata = serde_yaml_ng::from_str(&text)
        .with_context(|| format!("cannot read {}", meta_path.display()))?;
    let info = meta.rosbag2_bagfile_information;
    if !matches!(info.storage_identifier.as_str(), "mcap" | "sqlite3") {
        bail!(
            "{}: storage '{}' is not supported (mcap and sqlite3 are; convert it with \
             `ros2 bag convert` to storage_id mcap)",
            dir.display(),
            info.storage_identifier
        );
    }
    if !info.compression_format.is_empty() {
        bail!(
            "{}: compressed bags ({}) are not supported (write an uncompressed copy with \
             `ros2 bag convert`)",
            dir.display(),
            info.compression_format
        );
    }
    let files: Vec<_> = info
        .relative_file_paths
        .iter()
        .map(|f| dir.join(f))
        .collect();
    if files.is_empty() {
        bail!("{}: metadata.yaml lists no storage files", dir.display());
    }
    if let Some(missing) = files.iter().find(|f| !f.is_file()) {
        bail!(
            "{}: metadata.yaml lists {}, which is missing",
            dir.display(),
            missing.display()
        );
    }
    Ok(BagFiles {
        storage: info.storage_identifier,
        files,
    })
}

/// What `metadata.yaml` says of one topic.
pub struct TopicSummary {
    pub name: String,
    pub type_name: String,
    pub count: u64,
}

/// Write `metadata.yaml` for a one-file MCAP bag in `dir` (`file` relative to it) spanning
/// `[start_ns, end_ns]`.
pub fn write(
    dir: &Path,
    file: &str,
    topics: &[TopicSummary],
    start_ns: u64,
    end_ns: u64,
) -> Result<()> {
    let count: u64 = topics.iter().map(|t| t.count).sum();
    let duration = end_ns.saturating_sub(start_ns);
    let mut text = String::from("rosbag2_bagfile_information:\n  version: 9\n");
    text.push_str("  storage_identifier: mcap\n");
    text.push_str(&format!(
        "  duration:\n    nanoseconds: {duration}\n  starting_time:\n    \
         nanoseconds_since_epoch: {start_ns}\n  message_count: {count}\n"
    ));
    text.push_str("  topics_with_message_count:\n");
    for t in topics {
        text.push_str(&format!(
            "    - topic_metadata:\n        name: {}\n        type: {}\n        \
             serialization_format: cdr\n        offered_qos_profiles: []\n        \
             type_description_hash: ''\n      message_count: {}\n",
            t.name, t.type_name, t.count
        ));
    }
    text.push_str("  compression_format: ''\n  compression_mode: ''\n");
    text.push_str(&format!(
        "  relative_file_paths:\n    - {file}\n  files:\n    - path: {file}\n      \
         starting_time:\n        nanoseconds_since_epoch: {start_ns}\n      duration:\n        \
         nanoseconds: {duration}\n      message_count: {count}\n"
    ));
    text.push_str("  custom_data: {}\n  ros_distro: jazzy\n");
    let path = dir.join("metadata.yaml");
    std::fs::write(&path, text).with_context(|| format!("cannot write {}", path.display()))?;
    // Checked by reading it back, so a format slip fails here and not in someone's `ros2 bag`.
    let _: BTreeMap<String, serde_yaml_ng::Value> =
        serde_yaml_ng::from_str(&std::fs::read_to_string(&path)?)?;
    bag_files(dir).map(|_| ())
}
