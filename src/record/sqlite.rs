//! rosbag2's SQLite3 storage (`.db3`, the default before Iron): the `topics` and `messages`
//! tables read in insertion order, a batch at a time, so memory stays bounded whatever the bag's
//! length. Reading only; SQLite itself is the `rusqlite` crate.

use super::read::RawMessage;
use anyhow::{Context, Result};
use rusqlite::{Connection, OpenFlags};
use std::collections::{HashMap, VecDeque};
use std::path::Path;

/// Messages per query: a few images, so a batch stays a few MB.
const BATCH: i64 = 8;

pub struct SqliteReader {
    connection: Connection,
    /// topic id -> (name, type).
    topics: HashMap<i64, (String, String)>,
    last_id: i64,
    batch: VecDeque<RawMessage>,
    /// An error met after some messages of a batch: returned once those are read.
    error: Option<anyhow::Error>,
    done: bool,
}

impl SqliteReader {
    pub fn open(path: &Path) -> Result<Self> {
        let connection = Connection::open_with_flags(
            path,
            OpenFlags::SQLITE_OPEN_READ_ONLY | OpenFlags::SQLITE_OPEN_NO_MUTEX,
        )
        .with_context(|| format!("cannot open {} as SQLite", path.display()))?;
        let topics = {
            let mut statement = connection
                .prepare("SELECT id, name, type FROM topics")
                .with_context(|| format!("{} has no rosbag2 topics table", path.display()))?;
            let rows = statement.query_map([], |r| Ok((r.get(0)?, (r.get(1)?, r.get(2)?))))?;
            rows.collect::<Result<HashMap<_, _>, _>>()?
        };
        Ok(Self {
            connection,
            topics,
            last_id: i64::MIN,
            batch: VecDeque::new(),
            error: None,
            done: false,
        })
    }

    /// The next batch of messages after the last one read.
    fn fill(&mut self) -> Result<()> {
        let mut statement = self.connection.prepare_cached(
            "SELECT id, topic_id, timestamp, data FROM messages WHERE id > ?1 ORDER BY id LIMIT ?2",
        )?;
        let mut rows = statement.query((self.last_id, BATCH))?;
        while let Some(row) = rows.next()? {
            let (id, topic_id, stamp): (i64, i64, i64) = (row.get(0)?, row.get(1)?, row.get(2)?);
            let data: Vec<u8> = row.get(3)?;
            self.last_id = id;
            let Some((topic, schema)) = self.topics.get(&topic_id) else {
                anyhow::bail!("message {id} names topic id {topic_id}, which the bag lacks");
            };
            self.batch.push_back(RawMessage {
                topic: topic.clone(),
                schema: schema.clone(),
                time: stamp as f64 * 1e-9,
                data,
            });
        }
        Ok(())
    }
}

impl Iterator for SqliteReader {
    type Item = Result<RawMessage>;

    fn next(&mut self) -> Option<Self::Item> {
        if self.batch.is_empty() && !self.done {
            if let Err(e) = self.fill() {
                self.done = true;
                self.error = Some(e);
            }
            self.done |= self.batch.is_empty();
        }
        match self.batch.pop_front() {
            Some(m) => Some(Ok(m)),
            None => self.error.take().map(Err),
        }
    }
}
