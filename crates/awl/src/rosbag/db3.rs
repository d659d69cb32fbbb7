//! rosbag2 sqlite3 files (`.db3`, Humble's default storage): the `topics` and `messages` tables,
//! messages streamed by one query ordered by timestamp (SQLite pages them in; the file is never
//! held in memory).

use std::path::Path;

use rusqlite::{Connection, OpenFlags};

use crate::error::{Error, Result};
use crate::rosbag::BagMessage;

fn open(path: &Path) -> Result<Connection> {
    Connection::open_with_flags(path, OpenFlags::SQLITE_OPEN_READ_ONLY | OpenFlags::SQLITE_OPEN_NO_MUTEX)
        .map_err(|e| Error::format(path, format!("not a readable rosbag2 sqlite3 file: {e}")))
}

fn bad(path: &Path, e: &rusqlite::Error) -> Error {
    Error::format(path, format!("truncated or damaged rosbag2 sqlite3 file: {e}"))
}

/// The bag's topics: (id, name, type, serialization format).
fn topics(path: &Path, db: &Connection) -> Result<Vec<(i64, String, String, String)>> {
    let mut statement =
        db.prepare("SELECT id, name, type, serialization_format FROM topics").map_err(|e| bad(path, &e))?;
    let rows =
        statement.query_map([], |r| Ok((r.get(0)?, r.get(1)?, r.get(2)?, r.get(3)?))).map_err(|e| bad(path, &e))?;
    rows.collect::<rusqlite::Result<Vec<_>>>().map_err(|e| bad(path, &e))
}

/// The number of messages in the file (the progress bar's length).
pub(crate) fn message_count(path: &Path) -> Result<u64> {
    let db = open(path)?;
    let n: i64 = db.query_row("SELECT COUNT(*) FROM messages", [], |r| r.get(0)).map_err(|e| bad(path, &e))?;
    Ok(n.max(0) as u64)
}

/// Calls `f` on every message of `path` whose topic `wanted` accepts, by timestamp (the others'
/// data is not read); `progress` gets the count of messages read so far every 64 messages.
pub(crate) fn for_each(
    path: &Path,
    wanted: &dyn Fn(&str) -> bool,
    progress: &mut dyn FnMut(u64),
    f: &mut dyn FnMut(&BagMessage<'_>) -> Result<()>,
) -> Result<()> {
    let db = open(path)?;
    let topics: Vec<_> = topics(path, &db)?.into_iter().filter(|t| wanted(&t.1)).collect();
    for (_, name, _, format) in &topics {
        if format != "cdr" {
            return Err(Error::format(
                path,
                format!("topic {name}: serialization format `{format}`, expected `cdr` (a ROS 2 recording)"),
            ));
        }
    }
    if topics.is_empty() {
        return Ok(());
    }
    let ids: Vec<String> = topics.iter().map(|t| t.0.to_string()).collect();
    let sql = format!(
        "SELECT topic_id, timestamp, data FROM messages WHERE topic_id IN ({}) ORDER BY timestamp, id",
        ids.join(",")
    );
    let mut statement = db.prepare(&sql).map_err(|e| bad(path, &e))?;
    let mut rows = statement.query([]).map_err(|e| bad(path, &e))?;
    let mut count = 0u64;
    while let Some(row) = rows.next().map_err(|e| bad(path, &e))? {
        let id: i64 = row.get(0).map_err(|e| bad(path, &e))?;
        let stamp: i64 = row.get(1).map_err(|e| bad(path, &e))?;
        let data = row.get_ref(2).and_then(|v| Ok(v.as_blob()?)).map_err(|e| bad(path, &e))?;
        let Some((_, topic, type_name, _)) = topics.iter().find(|t| t.0 == id) else { continue };
        f(&BagMessage { topic, type_name, log_time_ns: stamp.max(0) as u64, data })?;
        count += 1;
        if count.is_multiple_of(64) {
            progress(count);
        }
    }
    progress(count);
    Ok(())
}
