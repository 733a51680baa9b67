//! Reading recordings as a stream: an `.mcap` or `.db3` file, or a rosbag2 directory (its
//! `metadata.yaml` and storage files in the order it lists them), yielded message by message:
//! an MCAP file with a summary in log-time order (its chunks read as the order needs them: a bag
//! whose writer logged one camera after another still replays them together), one without (a
//! truncated file) and SQLite in storage order. Memory is bounded by the MCAP chunks that overlap
//! in time or one SQLite batch, whatever the bag's length. A damaged or truncated file ends the
//! stream and is kept in `problem()`, never a panic.

use super::metadata;
use super::sqlite::SqliteReader;
use anyhow::{Context, Result};
use mcap::sans_io::indexed_reader::{IndexedReadEvent, IndexedReader};
use mcap::sans_io::summary_reader::{SummaryReadEvent, SummaryReader, SummaryReaderOptions};
use std::collections::{HashMap, VecDeque};
use std::fs::File;
use std::io::{BufReader, Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};

/// One recorded message: topic, schema name, log time (s) and CDR payload.
pub struct RawMessage {
    pub topic: String,
    pub schema: String,
    pub time: f64,
    pub data: Vec<u8>,
}

/// One storage file being read.
enum Storage {
    Mcap {
        reader: Box<mcap::io::MessageReader<BufReader<File>>>,
        path: PathBuf,
        read: usize,
    },
    /// An MCAP file with a summary, read through its chunk indexes in log-time order.
    McapIndexed {
        file: File,
        reader: Box<IndexedReader>,
        /// Topic and schema name per channel id.
        channels: HashMap<u16, (String, String)>,
        chunk: Vec<u8>,
        path: PathBuf,
        read: usize,
    },
    Sqlite {
        reader: Box<SqliteReader>,
        path: PathBuf,
        read: usize,
    },
}

/// What an indexed MCAP reader asked for next.
enum IndexedStep {
    Message(RawMessage),
    Chunk(u64, usize),
    End,
}

/// The summary of an MCAP file (channels, schemas, chunk indexes), or `None` when it has none
/// (a truncated file) or no chunk indexes.
fn mcap_summary(file: &mut File) -> Option<mcap::Summary> {
    let size = file.metadata().ok()?.len();
    let options = SummaryReaderOptions::default().with_file_size(size);
    let mut reader = SummaryReader::new_with_options(options);
    while let Some(event) = reader.next_event() {
        match event.ok()? {
            SummaryReadEvent::ReadRequest(n) => {
                let got = file.read(reader.insert(n)).ok()?;
                reader.notify_read(got);
            }
            SummaryReadEvent::SeekRequest(to) => reader.notify_seeked(file.seek(to).ok()?),
        }
    }
    reader.finish().filter(|s| !s.chunk_indexes.is_empty())
}

/// A recording's messages in storage order (see the module doc).
pub struct BagReader {
    storage: String,
    files: VecDeque<PathBuf>,
    current: Option<Storage>,
    problem: Option<String>,
    done: bool,
}

impl BagReader {
    /// Open `path`: an MCAP or SQLite3 file, or a rosbag2 directory. Refused with the reason when
    /// it is none of these or its metadata names files that are missing.
    pub fn open(path: &Path) -> Result<Self> {
        let (storage, files) = if path.is_dir() {
            let bag = metadata::bag_files(path)?;
            (bag.storage, bag.files)
        } else {
            if !path.is_file() {
                anyhow::bail!("recording {} does not exist", path.display());
            }
            let storage = match path.extension().and_then(|e| e.to_str()) {
                Some("db3") => "sqlite3",
                _ => "mcap",
            };
            (storage.to_string(), vec![path.to_path_buf()])
        };
        Ok(Self {
            storage,
            files: files.into(),
            current: None,
            problem: None,
            done: false,
        })
    }

    /// The storage plugin (`mcap` or `sqlite3`).
    pub fn storage(&self) -> &str {
        &self.storage
    }

    /// Why reading stopped early (a damaged or truncated file), once the stream has ended.
    pub fn problem(&self) -> Option<&str> {
        self.problem.as_deref()
    }

    fn open_next(&mut self) -> Result<bool> {
        let Some(path) = self.files.pop_front() else {
            return Ok(false);
        };
        self.current = Some(if self.storage == "sqlite3" {
            Storage::Sqlite {
                reader: Box::new(SqliteReader::open(&path)?),
                path,
                read: 0,
            }
        } else {
            let mut file = File::open(&path)
                .with_context(|| format!("cannot read recording {}", path.display()))?;
            let indexed = mcap_summary(&mut file).and_then(|summary| {
                let channels = summary
                    .channels
                    .iter()
                    .map(|(id, c)| {
                        let schema = c.schema.as_ref().map(|s| s.name.clone());
                        (*id, (c.topic.clone(), schema.unwrap_or_default()))
                    })
                    .collect();
                Some((IndexedReader::new(&summary).ok()?, channels))
            });
            if let Some((reader, channels)) = indexed {
                self.current = Some(Storage::McapIndexed {
                    file,
                    reader: Box::new(reader),
                    channels,
                    chunk: Vec::new(),
                    path,
                    read: 0,
                });
                return Ok(true);
            }
            file.seek(SeekFrom::Start(0))
                .with_context(|| format!("cannot read recording {}", path.display()))?;
            Storage::Mcap {
                reader: Box::new(mcap::io::MessageReader::new(BufReader::with_capacity(
                    1 << 20,
                    file,
                ))),
                path,
                read: 0,
            }
        });
        Ok(true)
    }

    fn stop(&mut self, problem: String) -> Option<RawMessage> {
        self.problem = Some(problem);
        self.done = true;
        self.current = None;
        None
    }
}

impl Iterator for BagReader {
    type Item = RawMessage;

    fn next(&mut self) -> Option<RawMessage> {
        while !self.done {
            let next = match &mut self.current {
                None => match self.open_next() {
                    Ok(true) => continue,
                    Ok(false) => {
                        self.done = true;
                        return None;
                    }
                    Err(e) => return self.stop(format!("{e:#}")),
                },
                Some(Storage::Mcap { reader, path, read }) => match reader.next() {
                    Some(Ok(m)) => {
                        *read += 1;
                        Ok(Some(RawMessage {
                            topic: m.channel.topic.clone(),
                            schema: m
                                .channel
                                .schema
                                .as_ref()
                                .map(|s| s.name.clone())
                                .unwrap_or_default(),
                            time: m.log_time as f64 * 1e-9,
                            data: m.data.into_owned(),
                        }))
                    }
                    Some(Err(e)) if *read == 0 => Err(format!(
                        "{} is not a readable MCAP file: {e}",
                        path.display()
                    )),
                    Some(Err(e)) => Err(format!(
                        "{} is damaged after {read} messages: {e}",
                        path.display()
                    )),
                    None => Ok(None),
                },
                Some(Storage::McapIndexed {
                    file,
                    reader,
                    channels,
                    chunk,
                    path,
                    read,
                }) => {
                    let damaged = |e: &dyn std::fmt::Display, read: usize| {
                        format!("{} is damaged after {read} messages: {e}", path.display())
                    };
                    let step = match reader.next_event() {
                        None => Ok(IndexedStep::End),
                        Some(Err(e)) => Err(damaged(&e, *read)),
                        Some(Ok(IndexedReadEvent::ReadChunkRequest { offset, length })) => {
                            Ok(IndexedStep::Chunk(offset, length))
                        }
                        Some(Ok(IndexedReadEvent::Message { header, data })) => {
                            let (topic, schema) = channels
                                .get(&header.channel_id)
                                .cloned()
                                .unwrap_or_default();
                            Ok(IndexedStep::Message(RawMessage {
                                topic,
                                schema,
                                time: header.log_time as f64 * 1e-9,
                                data: data.to_vec(),
                            }))
                        }
                    };
                    match step {
                        Ok(IndexedStep::Message(m)) => {
                            *read += 1;
                            Ok(Some(m))
                        }
                        Ok(IndexedStep::End) => Ok(None),
                        Ok(IndexedStep::Chunk(offset, length)) => {
                            chunk.resize(length, 0);
                            let loaded = file
                                .seek(SeekFrom::Start(offset))
                                .and_then(|_| file.read_exact(chunk))
                                .map_err(|e| damaged(&e, *read))
                                .and_then(|_| {
                                    reader
                                        .insert_chunk_record_data(offset, chunk)
                                        .map_err(|e| damaged(&e, *read))
                                });
                            match loaded {
                                Ok(()) => continue,
                                Err(e) => Err(e),
                            }
                        }
                        Err(e) => Err(e),
                    }
                }
                Some(Storage::Sqlite { reader, path, read }) => match reader.next() {
                    Some(Ok(m)) => {
                        *read += 1;
                        Ok(Some(m))
                    }
                    Some(Err(e)) => Err(format!(
                        "{} is damaged after {read} messages: {e:#}",
                        path.display()
                    )),
                    None => Ok(None),
                },
            };
            match next {
                Ok(Some(m)) => return Some(m),
                Ok(None) => self.current = None,
                Err(problem) => return self.stop(problem),
            }
        }
        None
    }
}

/// Every message of a recording (see `BagReader`), and why reading stopped early if it did. For
/// tools and tests on small recordings; replay streams.
pub fn read_messages(path: &Path) -> Result<(Vec<RawMessage>, Option<String>)> {
    let mut reader = BagReader::open(path)?;
    let messages: Vec<RawMessage> = reader.by_ref().collect();
    Ok((messages, reader.problem().map(str::to_string)))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::msgs::{self, Header, JointState, Time};
    use crate::record::{JOINT_STATES, RecordingWriter};

    #[test]
    fn writes_and_reads_back_and_survives_truncation() {
        let dir = std::env::temp_dir().join(format!("pegs-rec-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("r.mcap");
        joint_file(&path, 0..200);
        let (msgs_read, problem) = read_messages(&path).unwrap();
        assert!(problem.is_none());
        assert_eq!(msgs_read.len(), 200);
        assert_eq!(msgs_read[0].schema, "sensor_msgs/msg/JointState");
        let js: JointState = msgs::from_cdr(&msgs_read[150].data).unwrap();
        assert_eq!(js.position, vec![150.0]);
        assert!((msgs_read[150].time - 1.5).abs() < 1e-9);
        // Cut the file in the middle: no panic, a clear report, whatever was intact.
        let bytes = std::fs::read(&path).unwrap();
        std::fs::write(dir.join("cut.mcap"), &bytes[..bytes.len() / 2]).unwrap();
        let (partial, problem) = read_messages(&dir.join("cut.mcap")).unwrap();
        assert!(problem.is_some(), "truncation must be reported");
        for m in &partial {
            msgs::from_cdr::<JointState>(&m.data).expect("what is returned is intact");
        }
        // Cut inside the first chunk: its messages are lost, and that is reported too.
        std::fs::write(dir.join("cut2.mcap"), &bytes[..100]).unwrap();
        let (partial, problem) = read_messages(&dir.join("cut2.mcap")).unwrap();
        assert!(
            problem.is_some() && partial.len() < 200,
            "{} messages from 100 bytes",
            partial.len()
        );
        std::fs::write(dir.join("junk.mcap"), b"not an mcap").unwrap();
        let (none, problem) = read_messages(&dir.join("junk.mcap")).unwrap();
        assert!(none.is_empty() && problem.is_some());
    }

    /// An MCAP file whose writer logged its messages out of time order (one stream after another,
    /// as a merge or a per-camera importer does) is read in log-time order.
    #[test]
    fn an_mcap_file_is_read_in_log_time_order_whatever_the_order_it_was_written_in() {
        let dir = std::env::temp_dir().join(format!("pegs-order-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("late_first.mcap");
        joint_file(&path, (50..100).chain(0..50));
        let (read, problem) = read_messages(&path).unwrap();
        assert!(problem.is_none(), "{problem:?}");
        let order: Vec<f64> = read
            .iter()
            .map(|m| msgs::from_cdr::<JointState>(&m.data).unwrap().position[0])
            .collect();
        assert_eq!(order, (0..100).map(|k| k as f64).collect::<Vec<_>>());
        assert!(read.windows(2).all(|w| w[0].time <= w[1].time));
        let _ = std::fs::remove_dir_all(&dir);
    }

    /// Joint states k (position k, stamp k / 100 s) for k in `times`, into the MCAP file `path`.
    fn joint_file(path: &Path, times: impl Iterator<Item = usize>) {
        let mut w = RecordingWriter::create(path).unwrap();
        for k in times {
            let t = Time::from_seconds(k as f64 * 0.01);
            let js = JointState {
                header: Header {
                    stamp: t,
                    frame_id: String::new(),
                },
                name: vec!["j".into()],
                position: vec![k as f64],
                ..Default::default()
            };
            w.write(JOINT_STATES, msgs::schema::joint_state(), t, &js)
                .unwrap();
        }
        w.finish().unwrap();
    }

    /// A rosbag2 directory split into two storage files is read as one recording, in the order
    /// its metadata lists them; other storages, missing files and directories that are not bags
    /// are refused, naming what is wrong.
    #[test]
    fn a_rosbag2_directory_reads_its_storage_files_in_order() {
        let dir = std::env::temp_dir().join(format!("pegs-bag-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        joint_file(&dir.join("bag_0.mcap"), 0..50);
        joint_file(&dir.join("bag_1.mcap"), 50..80);
        let metadata = |storage: &str, files: &[&str]| {
            let list: String = files.iter().map(|f| format!("  - {f}\n")).collect();
            let text = format!(
                "rosbag2_bagfile_information:\n  version: 9\n  storage_identifier: {storage}\n  \
                 compression_format: ''\n  relative_file_paths:\n{list}"
            );
            std::fs::write(dir.join("metadata.yaml"), text).unwrap();
        };
        metadata("mcap", &["bag_0.mcap", "bag_1.mcap"]);
        let (read, problem) = read_messages(&dir).unwrap();
        assert!(problem.is_none());
        let positions: Vec<f64> = read
            .iter()
            .map(|m| msgs::from_cdr::<JointState>(&m.data).unwrap().position[0])
            .collect();
        assert_eq!(positions, (0..80).map(|k| k as f64).collect::<Vec<_>>());
        let refused = |why: &str| {
            let e = read_messages(&dir).err().expect("refused");
            let text = format!("{e:#}");
            assert!(text.contains(why), "{text}");
        };
        metadata("bagfile", &["bag_0.bag"]);
        refused("storage 'bagfile' is not supported");
        metadata("mcap", &["bag_0.mcap", "bag_2.mcap"]);
        refused("bag_2.mcap, which is missing");
        std::fs::remove_file(dir.join("metadata.yaml")).unwrap();
        refused("without metadata.yaml");
    }

    /// A SQLite3 storage file laid out as rosbag2 writes it (topics, messages in insertion order)
    /// reads back message for message, across batches, and names a message on a missing topic.
    #[test]
    fn a_sqlite3_storage_file_streams_in_insertion_order() {
        let dir = std::env::temp_dir().join(format!("pegs-db3-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("bag_0.db3");
        let db = rusqlite::Connection::open(&path).unwrap();
        db.execute_batch(
            "CREATE TABLE topics(id INTEGER PRIMARY KEY, name TEXT NOT NULL, type TEXT NOT NULL, \
             serialization_format TEXT NOT NULL, offered_qos_profiles TEXT NOT NULL); \
             CREATE TABLE messages(id INTEGER PRIMARY KEY, topic_id INTEGER NOT NULL, \
             timestamp INTEGER NOT NULL, data BLOB NOT NULL); \
             INSERT INTO topics VALUES (1, '/joint_states', 'sensor_msgs/msg/JointState', 'cdr', '');",
        )
        .unwrap();
        for k in 0..30 {
            let js = JointState {
                name: vec!["j".into()],
                position: vec![k as f64],
                ..Default::default()
            };
            db.execute(
                "INSERT INTO messages(topic_id, timestamp, data) VALUES (1, ?1, ?2)",
                (k * 10_000_000i64, msgs::to_cdr(&js).unwrap()),
            )
            .unwrap();
        }
        let (read, problem) = read_messages(&path).unwrap();
        assert!(problem.is_none(), "{problem:?}");
        let positions: Vec<f64> = read
            .iter()
            .map(|m| msgs::from_cdr::<JointState>(&m.data).unwrap().position[0])
            .collect();
        assert_eq!(positions, (0..30).map(|k| k as f64).collect::<Vec<_>>());
        assert_eq!(read[29].topic, "/joint_states");
        assert!((read[29].time - 0.29).abs() < 1e-9);
        db.execute(
            "INSERT INTO messages(topic_id, timestamp, data) VALUES (7, 0, x'00')",
            (),
        )
        .unwrap();
        let (read, problem) = read_messages(&path).unwrap();
        assert_eq!(read.len(), 30);
        assert!(problem.unwrap().contains("topic id 7"));
    }
}
