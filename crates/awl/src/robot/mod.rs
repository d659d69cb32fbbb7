//! Sending a plan's programs to a robot controller over TCP: Universal Robots' primary / secondary
//! client interface ([`ur`], ports 30001 / 30002: a URScript program as text) and Techman's listen
//! node ([`techman`], port 5890: `$TMSCT` packets with their checksums, each acknowledged). Each
//! connection, read and write has a timeout; an unreachable host, a silent controller, a negative
//! acknowledgement or a malformed reply is an [`crate::Error::Robot`] naming the address and what
//! was being sent. The only network code of the library. [`statements`]: the statements awl's
//! programs are made of, checked before anything is sent.

pub mod statements;
pub mod techman;
pub mod ur;

use std::net::{TcpStream, ToSocketAddrs};
use std::time::Duration;

use crate::error::{Error, Result};

/// UR's primary client interface port.
pub const UR_PRIMARY_PORT: u16 = 30001;
/// UR's secondary client interface port (the default of `awl send --ur`).
pub const UR_SECONDARY_PORT: u16 = 30002;
/// Techman's listen-node port.
pub const TECHMAN_PORT: u16 = 5890;

/// Connects to `host:port` within `timeout` (each resolved address tried), and sets the stream's
/// read and write timeouts to it.
///
/// # Errors
/// [`Error::Invalid`] for a zero timeout; [`Error::Robot`] when the name does not resolve or no
/// address accepts the connection in time.
pub fn connect(host: &str, port: u16, timeout: Duration) -> Result<TcpStream> {
    let address = format!("{host}:{port}");
    if timeout.is_zero() {
        return Err(Error::invalid("timeout", "must be above zero"));
    }
    let addrs: Vec<_> = (host, port)
        .to_socket_addrs()
        .map_err(|e| Error::robot(&address, format!("the host name does not resolve: {e}")))?
        .collect();
    let mut last = String::from("no address");
    for a in &addrs {
        match TcpStream::connect_timeout(a, timeout) {
            Ok(stream) => {
                let set = |r: std::io::Result<()>| r.map_err(|e| Error::robot(&address, format!("socket setup: {e}")));
                set(stream.set_read_timeout(Some(timeout)))?;
                set(stream.set_write_timeout(Some(timeout)))?;
                set(stream.set_nodelay(true))?;
                return Ok(stream);
            }
            Err(e) => last = e.to_string(),
        }
    }
    Err(Error::robot(
        &address,
        format!(
            "no connection within {:.1} s ({last}): check the address, the port and that the controller is on",
            timeout.as_secs_f64()
        ),
    ))
}

/// Whether an I/O error is a timeout (the platforms report it as either kind).
pub(crate) fn is_timeout(e: &std::io::Error) -> bool {
    matches!(e.kind(), std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut)
}
