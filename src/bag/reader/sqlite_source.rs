//! The sqlite3 source of [`super::BagReader`]: the messages table of a rosbag2 database,
//! paged in timestamp order through `rusqlite`.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use super::super::schemas::normalise_type;
use super::super::BagError;
use super::{BagMessage, TopicInfo};

/// A row of the topics table.
struct SqliteTopic {
    name: String,
    /// Normalised (`pkg/msg/Name`).
    msg_type: String,
    serialization_format: String,
    /// `offered_qos_profiles` (none when empty, or in a bag older than the column).
    qos: Option<String>,
}

/// The topics table by id: with its `offered_qos_profiles` column where the bag has one.
fn read_topics(conn: &rusqlite::Connection) -> rusqlite::Result<HashMap<i64, SqliteTopic>> {
    let with_qos = "SELECT id, name, type, serialization_format, offered_qos_profiles FROM topics";
    let without_qos = "SELECT id, name, type, serialization_format, '' FROM topics";
    let mut stmt = match conn.prepare(with_qos) {
        Ok(stmt) => stmt,
        // A bag older than the column (rosbag2 before Foxy).
        Err(_) => conn.prepare(without_qos)?,
    };
    let rows = stmt.query_map([], |r| {
        let qos: Option<String> = r.get(4)?;
        Ok((
            r.get::<_, i64>(0)?,
            SqliteTopic {
                name: r.get(1)?,
                msg_type: normalise_type(&r.get::<_, String>(2)?),
                serialization_format: r.get(3)?,
                qos: qos.filter(|q| !q.trim().is_empty()),
            },
        ))
    })?;
    rows.collect()
}

/// Pages through the messages table of a rosbag2 sqlite3 database in timestamp order.
pub(super) struct SqliteSource {
    path: PathBuf,
    conn: rusqlite::Connection,
    topics: HashMap<i64, SqliteTopic>,
    counts: HashMap<i64, u64>,
    page: std::collections::VecDeque<BagMessage>,
    page_size: usize,
    after: Option<(i64, i64)>,
    done: bool,
}

impl SqliteSource {
    pub fn open(path: &Path, page_size: usize) -> Result<Self, BagError> {
        let sql = |e: rusqlite::Error| BagError::Format {
            path: path.to_path_buf(),
            reason: format!("sqlite3: {e}"),
        };
        let conn = rusqlite::Connection::open_with_flags(
            path,
            rusqlite::OpenFlags::SQLITE_OPEN_READ_ONLY | rusqlite::OpenFlags::SQLITE_OPEN_NO_MUTEX,
        )
        .map_err(sql)?;
        let topics = read_topics(&conn).map_err(sql)?;
        let mut counts = HashMap::new();
        {
            let mut stmt = conn
                .prepare("SELECT topic_id, COUNT(*) FROM messages GROUP BY topic_id")
                .map_err(sql)?;
            let rows = stmt
                .query_map([], |r| Ok((r.get::<_, i64>(0)?, r.get::<_, i64>(1)?)))
                .map_err(sql)?;
            for row in rows {
                let (id, n) = row.map_err(sql)?;
                counts.insert(id, u64::try_from(n).unwrap_or(0));
            }
        }
        Ok(Self {
            path: path.to_path_buf(),
            conn,
            topics,
            counts,
            page: Default::default(),
            page_size,
            after: None,
            done: false,
        })
    }

    pub fn topic_infos(&self) -> Vec<TopicInfo> {
        let definitions = self.definitions();
        let mut v: Vec<TopicInfo> = self
            .topics
            .iter()
            .map(|(id, t)| TopicInfo {
                name: t.name.clone(),
                msg_type: t.msg_type.clone(),
                encoding: t.serialization_format.clone(),
                count: Some(self.counts.get(id).copied().unwrap_or(0)),
                schema: definitions.get(&t.msg_type).cloned(),
                qos: t.qos.clone(),
            })
            .collect();
        v.sort_by(|a, b| a.name.cmp(&b.name));
        v
    }

    /// The `ros2msg` message definitions rosbag2 (Iron and later) records per type, by
    /// normalised type name; none in older bags (no `message_definitions` table).
    fn definitions(&self) -> HashMap<String, Vec<u8>> {
        let query = "SELECT topic_type, encoding, encoded_message_definition \
                     FROM message_definitions";
        let Ok(mut stmt) = self.conn.prepare(query) else {
            return HashMap::new();
        };
        let rows = stmt.query_map([], |r| {
            Ok((
                r.get::<_, String>(0)?,
                r.get::<_, String>(1)?,
                r.get::<_, String>(2)?,
            ))
        });
        let Ok(rows) = rows else {
            return HashMap::new();
        };
        rows.flatten()
            .filter(|(_, encoding, text)| encoding == "ros2msg" && !text.is_empty())
            .map(|(ty, _, text)| (normalise_type(&ty), text.into_bytes()))
            .collect()
    }

    fn fill_page(&mut self) -> Result<(), BagError> {
        let sql = |e: rusqlite::Error| BagError::Format {
            path: self.path.clone(),
            reason: format!("sqlite3: {e}"),
        };
        let (t, id) = self.after.unwrap_or((i64::MIN, i64::MIN));
        let mut stmt = self
            .conn
            .prepare_cached(
                "SELECT id, topic_id, timestamp, data FROM messages \
                 WHERE timestamp > ?1 OR (timestamp = ?1 AND id > ?2) \
                 ORDER BY timestamp, id LIMIT ?3",
            )
            .map_err(sql)?;
        let limit = i64::try_from(self.page_size).unwrap_or(256);
        let rows = stmt
            .query_map(rusqlite::params![t, id, limit], |r| {
                Ok((
                    r.get::<_, i64>(0)?,
                    r.get::<_, i64>(1)?,
                    r.get::<_, i64>(2)?,
                    r.get::<_, Vec<u8>>(3)?,
                ))
            })
            .map_err(sql)?;
        let mut n = 0;
        for row in rows {
            let (id, topic_id, timestamp, data) = row.map_err(sql)?;
            n += 1;
            self.after = Some((timestamp, id));
            let Some(SqliteTopic {
                name: topic,
                msg_type,
                serialization_format: fmt,
                ..
            }) = self.topics.get(&topic_id)
            else {
                return Err(BagError::Format {
                    path: self.path.clone(),
                    reason: format!("message {id} refers to unknown topic id {topic_id}"),
                });
            };
            if fmt != "cdr" {
                return Err(BagError::Format {
                    path: self.path.clone(),
                    reason: format!("topic {topic} has serialization_format '{fmt}', not 'cdr'"),
                });
            }
            let t = u64::try_from(timestamp).unwrap_or(0);
            self.page.push_back(BagMessage {
                topic: topic.clone(),
                msg_type: msg_type.clone(),
                log_time_ns: t,
                publish_time_ns: t,
                data,
            });
        }
        if n == 0 {
            self.done = true;
        }
        Ok(())
    }

    pub fn next_message(&mut self) -> Result<Option<BagMessage>, BagError> {
        if self.page.is_empty() && !self.done {
            self.fill_page()?;
        }
        Ok(self.page.pop_front())
    }
}
