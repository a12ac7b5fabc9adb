//! The sqlite3 source of [`super::BagReader`]: the messages table of a rosbag2 database,
//! paged in timestamp order through `rusqlite`. A database cut short (a recording killed
//! mid-write, a copy that stopped) is read as far as its pages go, in row (recording) order,
//! and where it ends is reported as damage: how many messages were read, the last one's time.

use std::collections::{HashMap, VecDeque};
use std::fs::File;
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

/// Why an sqlite3 file cannot be read whole.
struct Damage {
    why: String,
    /// Cut short (the file ends before its pages do), rather than a damaged page inside.
    truncated: bool,
}

/// SQLite's own "corrupt" verdicts: a page missing or not what it should be.
fn is_corrupt(e: &rusqlite::Error) -> bool {
    matches!(
        e.sqlite_error_code(),
        Some(rusqlite::ErrorCode::DatabaseCorrupt | rusqlite::ErrorCode::NotADatabase)
    )
}

/// An sqlite3 file's length against its header: why it was cut short, if it was (the file
/// ends before the pages its header declares, or inside a page).
fn truncation(path: &Path) -> Result<Option<Damage>, BagError> {
    let mut file = File::open(path).map_err(|e| BagError::io(path, e))?;
    let len = file.metadata().map_err(|e| BagError::io(path, e))?.len();
    let mut header = [0u8; 100];
    let n = super::read_up_to(&mut file, &mut header).map_err(|e| BagError::io(path, e))?;
    let cut = |why: String| {
        Ok(Some(Damage {
            why,
            truncated: true,
        }))
    };
    if n < header.len() {
        return cut(format!(
            "the file is {len} bytes, shorter than an sqlite3 header: cut short"
        ));
    }
    let page_size = match u16::from_be_bytes([header[16], header[17]]) {
        1 => 65536,
        p => u64::from(p),
    };
    if page_size < 512 || !page_size.is_power_of_two() {
        return Ok(None); // Not a size SQLite writes: SQLite says what is wrong.
    }
    let be32 =
        |i: usize| u32::from_be_bytes([header[i], header[i + 1], header[i + 2], header[i + 3]]);
    // The header's page count holds when it was written with the change counter it carries.
    let declared = u64::from(be32(28));
    if declared > 0 && be32(24) == be32(92) && declared * page_size > len {
        return cut(format!(
            "the file holds {} of the {declared} pages of {page_size} bytes its header declares \
             ({len} of {} bytes): cut short",
            len / page_size,
            declared * page_size
        ));
    }
    if len % page_size != 0 {
        return cut(format!(
            "the file ends {} bytes into page {} ({page_size} bytes a page): cut short",
            len % page_size,
            len / page_size + 1
        ));
    }
    Ok(None)
}

/// Lets SQLite read a file shorter than its header declares: the pages the file holds, any
/// page past them an error (SQLite's `writable_schema` recovery; the connection is read-only),
/// cells checked as they are read.
fn allow_short(conn: &rusqlite::Connection) -> rusqlite::Result<()> {
    conn.pragma_update(None, "writable_schema", true)?;
    conn.pragma_update(None, "cell_size_check", true)
}

/// Messages per topic id (a whole pass over the table's pages, not its data).
fn count_messages(conn: &rusqlite::Connection) -> rusqlite::Result<HashMap<i64, u64>> {
    let mut stmt = conn.prepare("SELECT topic_id, COUNT(*) FROM messages GROUP BY topic_id")?;
    let rows = stmt.query_map([], |r| {
        let n: i64 = r.get(1)?;
        Ok((r.get::<_, i64>(0)?, u64::try_from(n).unwrap_or(0)))
    })?;
    rows.collect()
}

/// A row of the messages table: id, topic id, timestamp, data.
type Row = (i64, i64, i64, Vec<u8>);

/// Pages through the messages table of a rosbag2 sqlite3 database in timestamp order (a
/// damaged one in row order, as far as it can be read).
pub(super) struct SqliteSource {
    path: PathBuf,
    conn: rusqlite::Connection,
    topics: HashMap<i64, SqliteTopic>,
    /// Messages per topic id; none in a damaged file.
    counts: Option<HashMap<i64, u64>>,
    page: VecDeque<BagMessage>,
    page_size: usize,
    /// The (timestamp, id) of the last row read.
    after: Option<(i64, i64)>,
    done: bool,
    /// Set when the file is found damaged; taken when that is reported, after the last
    /// message read.
    damage: Option<Damage>,
    /// Read in row order (the file was damaged before reading began).
    by_row: bool,
    /// Messages handed out, and the log time of the last.
    read: u64,
    last_ns: Option<u64>,
    /// Rows of a damaged file whose data lay on lost pages: skipped, counted.
    unreadable: u64,
    reported: bool,
    file_len: u64,
}

impl SqliteSource {
    /// Opens a database; one cut short or with a damaged page in its messages table is
    /// opened to be read as far as it goes. Nothing readable (its header or topics lost): an
    /// error saying why.
    pub fn open(path: &Path, page_size: usize) -> Result<Self, BagError> {
        let mut damage = truncation(path)?;
        let sql = |e: rusqlite::Error, damage: &Option<Damage>| BagError::Format {
            path: path.to_path_buf(),
            reason: match damage {
                Some(d) => format!("sqlite3: {e}; {}, and what is left cannot be read", d.why),
                None => format!("sqlite3: {e}"),
            },
        };
        let conn = rusqlite::Connection::open_with_flags(
            path,
            rusqlite::OpenFlags::SQLITE_OPEN_READ_ONLY | rusqlite::OpenFlags::SQLITE_OPEN_NO_MUTEX,
        )
        .map_err(|e| sql(e, &damage))?;
        if damage.is_some() {
            allow_short(&conn).map_err(|e| sql(e, &damage))?;
        }
        let topics = read_topics(&conn).map_err(|e| sql(e, &damage))?;
        let counts = match damage {
            Some(_) => None,
            None => match count_messages(&conn) {
                Ok(counts) => Some(counts),
                Err(e) if is_corrupt(&e) => {
                    damage = Some(Damage {
                        why: format!("a page of its messages table is damaged ({e})"),
                        truncated: false,
                    });
                    allow_short(&conn).map_err(|e| sql(e, &damage))?;
                    None
                }
                Err(e) => return Err(sql(e, &None)),
            },
        };
        Ok(Self {
            path: path.to_path_buf(),
            conn,
            topics,
            counts,
            page: VecDeque::new(),
            page_size,
            after: None,
            done: false,
            by_row: damage.is_some(),
            damage,
            read: 0,
            last_ns: None,
            unreadable: 0,
            reported: false,
            file_len: std::fs::metadata(path).map(|m| m.len()).unwrap_or(0),
        })
    }

    /// The damage of this file was reported (the last thing it gives): reading goes on with
    /// the bag's next file.
    pub fn damage_reported(&self) -> bool {
        self.reported
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
                count: (self.counts.as_ref()).map(|c| c.get(id).copied().unwrap_or(0)),
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

    /// The next rows in timestamp order; a damaged page met on the way ends the file there.
    fn fill_page(&mut self) -> Result<(), BagError> {
        let (t, id) = self.after.unwrap_or((i64::MIN, i64::MIN));
        let limit = i64::try_from(self.page_size).unwrap_or(256);
        let (rows, error) = self.query_rows(
            "SELECT id, topic_id, timestamp, data FROM messages \
             WHERE timestamp > ?1 OR (timestamp = ?1 AND id > ?2) \
             ORDER BY timestamp, id LIMIT ?3",
            rusqlite::params![t, id, limit],
        )?;
        let n = rows.len();
        for row in rows {
            self.push_row(row)?;
        }
        match error {
            Some(e) if is_corrupt(&e) => {
                self.damage = Some(Damage {
                    why: format!("a page is damaged ({e})"),
                    truncated: false,
                });
                self.done = true;
            }
            Some(e) => return Err(self.sql(e)),
            None if n == 0 => self.done = true,
            None => {}
        }
        Ok(())
    }

    /// The next rows of a damaged file in row (recording) order, up to the first that cannot
    /// be read: that one is skipped when the table still reaches a row after it (its data lay
    /// on lost pages), else the file ends there.
    fn fill_page_by_row(&mut self) -> Result<(), BagError> {
        let after = self.after.map_or(i64::MIN, |(_, id)| id);
        let limit = i64::try_from(self.page_size).unwrap_or(256);
        let (rows, error) = self.query_rows(
            "SELECT id, topic_id, timestamp, data FROM messages WHERE id > ?1 \
             ORDER BY id LIMIT ?2",
            rusqlite::params![after, limit],
        )?;
        let n = rows.len();
        for row in rows {
            self.push_row(row)?;
        }
        if error.is_none() {
            self.done = n == 0;
            return Ok(());
        }
        // The id of the row that failed lies on the table's own pages: found, it is skipped;
        // not found (or not reachable), the table ends here.
        let last = self.after.map_or(i64::MIN, |(_, id)| id);
        let next = self.conn.query_row(
            "SELECT id FROM messages WHERE id > ?1 ORDER BY id LIMIT 1",
            [last],
            |r| r.get::<_, i64>(0),
        );
        match next {
            Ok(id) => {
                self.unreadable += 1;
                self.after = Some((i64::MIN, id));
            }
            Err(_) => self.done = true,
        }
        Ok(())
    }

    /// The rows `query` gives, up to the first error (returned beside them).
    fn query_rows(
        &self,
        query: &str,
        params: impl rusqlite::Params,
    ) -> Result<(Vec<Row>, Option<rusqlite::Error>), BagError> {
        let mut stmt = self.conn.prepare_cached(query).map_err(|e| self.sql(e))?;
        let rows = stmt
            .query_map(params, |r| {
                Ok((r.get(0)?, r.get(1)?, r.get(2)?, r.get::<_, Vec<u8>>(3)?))
            })
            .map_err(|e| self.sql(e))?;
        let mut got = Vec::new();
        for row in rows {
            match row {
                Ok(row) => got.push(row),
                Err(e) => return Ok((got, Some(e))),
            }
        }
        Ok((got, None))
    }

    fn sql(&self, e: rusqlite::Error) -> BagError {
        BagError::Format {
            path: self.path.clone(),
            reason: format!("sqlite3: {e}"),
        }
    }

    fn push_row(&mut self, (id, topic_id, timestamp, data): Row) -> Result<(), BagError> {
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
        Ok(())
    }

    /// Where a damaged file ended: the file, why, how many messages were read and the last
    /// one's log time.
    fn damage_report(&self, damage: Damage) -> BagError {
        let order = if self.by_row { "recording" } else { "time" };
        let mut reason = format!(
            "{}: {} messages read (in {order} order)",
            damage.why, self.read
        );
        if let Some(ns) = self.last_ns {
            reason += &format!(
                ", the last logged at {}.{:09} s ({ns} ns)",
                ns / 1_000_000_000,
                ns % 1_000_000_000
            );
        }
        if self.unreadable > 0 {
            let rows = if self.unreadable == 1 { "row" } else { "rows" };
            reason += &format!(
                ", {} {rows} among them skipped (their data lay on lost pages)",
                self.unreadable
            );
        }
        reason += "; the rest of the file is damaged and was not read";
        if damage.truncated {
            BagError::Corrupt {
                path: self.path.clone(),
                offset: self.file_len,
                reason,
            }
        } else {
            BagError::Format {
                path: self.path.clone(),
                reason,
            }
        }
    }

    /// The next message; after the last one of a damaged file, the damage (once), then none.
    pub fn next_message(&mut self) -> Result<Option<BagMessage>, BagError> {
        while self.page.is_empty() && !self.done {
            if self.by_row {
                self.fill_page_by_row()?;
            } else {
                self.fill_page()?;
            }
        }
        if let Some(msg) = self.page.pop_front() {
            self.read += 1;
            self.last_ns = Some(msg.log_time_ns);
            return Ok(Some(msg));
        }
        match self.damage.take() {
            Some(damage) => {
                self.reported = true;
                Err(self.damage_report(damage))
            }
            None => Ok(None),
        }
    }
}
