//! A URScript program sent to a UR controller's primary or secondary client interface (port 30001
//! / 30002; Universal Robots' script manual, "Connecting to URControl", and its "Primary and
//! Secondary Interfaces" guide): the program as clear text, lines ended by `\n`, extended ASCII,
//! a `def` (or `sec`) in the first column, every other line indented, `end` in the first column
//! last. The controller streams its state (messages of a 4-byte big-endian length, then a 1-byte
//! type) on the same socket; the manual asks a client to read at least 79 bytes before closing so
//! that the program is not discarded: [`send_program`] reads them and checks their header, which
//! also shows that a UR controller is on the other end.

use std::io::{Read, Write};
use std::time::Duration;

use super::{connect, is_timeout};
use crate::error::{Error, Result};

/// Bytes to read from the controller before closing (the script manual's minimum).
pub const MIN_READ_BYTES: usize = 79;

/// Checks that `program` has the form the controller runs (module docs).
///
/// # Errors
/// [`Error::Invalid`] about `program` naming the line that breaks it.
pub fn check_program(program: &str) -> Result<()> {
    let bad = |m: String| Error::invalid("URScript program", m);
    if !program.is_ascii() {
        return Err(bad("must be ASCII text".into()));
    }
    if !program.ends_with('\n') {
        return Err(bad("must end with a newline".into()));
    }
    let lines: Vec<&str> = program.lines().collect();
    let first = lines.first().copied().unwrap_or("");
    if !(first.starts_with("def ") || first.starts_with("sec ")) {
        return Err(bad(format!("line 1 must start with `def` or `sec` in the first column, got `{first}`")));
    }
    let last = lines.len() - 1;
    if lines[last] != "end" {
        return Err(bad(format!("the last line must be `end` in the first column, got `{}`", lines[last])));
    }
    for (i, l) in lines.iter().enumerate().take(last).skip(1) {
        if !l.is_empty() && !l.starts_with([' ', '\t']) {
            return Err(bad(format!("line {} must be indented: `{l}`", i + 1)));
        }
    }
    Ok(())
}

/// What the controller sent back.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct UrReply {
    /// Bytes of the program sent.
    pub sent: usize,
    /// The first state message's length (its header), bytes.
    pub message_length: u32,
    /// Its type (16: robot state, 20: robot message, 25: ... as the guide lists).
    pub message_type: u8,
    /// Bytes read before closing.
    pub read: usize,
}

/// Sends `program` to `host:port` and reads the controller's first [`MIN_READ_BYTES`] bytes.
///
/// # Errors
/// [`Error::Invalid`] for a program of the wrong form ([`check_program`]); [`Error::Robot`] when
/// the connection fails, the write fails, nothing arrives within `timeout`, the connection closes
/// first, or the reply's header is not a UR state message (length below 5 or above 1 MB).
pub fn send_program(host: &str, port: u16, program: &str, timeout: Duration) -> Result<UrReply> {
    check_program(program)?;
    let address = format!("{host}:{port}");
    let mut stream = connect(host, port, timeout)?;
    stream
        .write_all(program.as_bytes())
        .and_then(|()| stream.flush())
        .map_err(|e| Error::robot(&address, format!("sending the program ({} bytes): {e}", program.len())))?;
    let mut buf = [0u8; MIN_READ_BYTES];
    let mut read = 0;
    while read < MIN_READ_BYTES {
        match stream.read(&mut buf[read..]) {
            Ok(0) => {
                return Err(Error::robot(
                    &address,
                    format!(
                        "the controller closed the connection after {read} bytes of state (the manual's minimum is \
                         {MIN_READ_BYTES}): the program may have been discarded"
                    ),
                ));
            }
            Ok(n) => read += n,
            Err(e) if is_timeout(&e) => {
                return Err(Error::robot(
                    &address,
                    format!(
                        "no robot state within {:.1} s after the program ({read} of {MIN_READ_BYTES} bytes): is this a \
                         UR controller's primary (30001) or secondary (30002) port?",
                        timeout.as_secs_f64()
                    ),
                ));
            }
            Err(e) => return Err(Error::robot(&address, format!("reading the robot state: {e}"))),
        }
    }
    let message_length = u32::from_be_bytes([buf[0], buf[1], buf[2], buf[3]]);
    let message_type = buf[4];
    if !(5..=1 << 20).contains(&message_length) {
        return Err(Error::robot(
            &address,
            format!("the reply does not start with a UR state message header (length {message_length})"),
        ));
    }
    Ok(UrReply { sent: program.len(), message_length, message_type, read })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn programs_of_the_wrong_form_are_named() {
        assert!(check_program("def p():\n  movej([0,0,0,0,0,0])\nend\n").is_ok());
        let e = check_program("def p():\nmovej([0,0,0,0,0,0])\nend\n").expect_err("refused").to_string();
        assert!(e.contains("line 2 must be indented"), "{e}");
        let e = check_program("def p():\n  x = 1\nend\np()\n").expect_err("refused").to_string();
        assert!(e.contains("last line must be `end`"), "{e}");
        assert!(check_program("# c\ndef p():\nend\n").expect_err("refused").to_string().contains("line 1"));
        assert!(check_program("def p():\nend").expect_err("refused").to_string().contains("newline"));
    }
}
