//! rosbag2 MCAP files (the default storage since ROS 2 Iron), streamed record by record with the
//! `mcap` crate's blocking reader: memory is bounded by the largest chunk, never the file.

use std::cell::Cell;
use std::io::Read;
use std::path::Path;
use std::rc::Rc;

use crate::error::{Error, Result};
use crate::rosbag::BagMessage;

/// A `Read` that counts the bytes it passes on (the progress of a pass through the file).
struct Counting<R> {
    inner: R,
    read: Rc<Cell<u64>>,
}

impl<R: Read> Read for Counting<R> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let n = self.inner.read(buf)?;
        self.read.set(self.read.get() + n as u64);
        Ok(n)
    }
}

/// Calls `f` on every message of `path` whose topic `wanted` accepts, in file order; `progress`
/// gets the bytes read so far every 64 messages.
pub(crate) fn for_each(
    path: &Path,
    wanted: &dyn Fn(&str) -> bool,
    progress: &mut dyn FnMut(u64),
    f: &mut dyn FnMut(&BagMessage<'_>) -> Result<()>,
) -> Result<()> {
    let file = crate::io::open_regular(path)?;
    let read = Rc::new(Cell::new(0));
    let reader = Counting { inner: std::io::BufReader::with_capacity(1 << 20, file), read: Rc::clone(&read) };
    let mut messages = mcap::io::MessageReader::new(reader);
    let mut count = 0u64;
    for message in messages.by_ref() {
        let message = message
            .map_err(|e| Error::format(path, format!("truncated or damaged MCAP file after {count} messages: {e}")))?;
        count += 1;
        let channel = &message.channel;
        if !wanted(&channel.topic) {
            continue;
        }
        if channel.message_encoding != "cdr" {
            return Err(Error::format(
                path,
                format!(
                    "topic {}: message encoding `{}`, expected `cdr` (a ROS 2 recording)",
                    channel.topic, channel.message_encoding
                ),
            ));
        }
        let type_name = channel.schema.as_ref().map_or("", |s| s.name.as_str());
        f(&BagMessage { topic: &channel.topic, type_name, log_time_ns: message.log_time, data: &message.data })?;
        if count.is_multiple_of(64) {
            progress(read.get());
        }
    }
    progress(read.get());
    Ok(())
}
