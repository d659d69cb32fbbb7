//! Techman listen-node packets sent to a TM controller (TCP port 5890; Techman's "Expression
//! Editor and Listen Node" manual). A packet is `$<header>,<length>,<data>,*<checksum>` and CR LF:
//! `<length>` counts the bytes of `<data>`, `<checksum>` is the XOR of every byte between `$` and
//! `*`, two upper-case hex digits ([`crate::pierce::tmsct_packet`] writes them). For a `$TMSCT`
//! packet (data `<id>,<script>`) the listen node answers `$TMSCT` with data `<id>,OK` when it took
//! the script, `<id>,ERROR;...` when not (the script's error lines), or `$CPERR` with an error code
//! (data `01` packet error, `02` checksum error, `03` header error, `04` packet data error, `F1`
//! not in a listen node) when the packet itself was bad. [`send_packets`] sends the packets one at
//! a time and waits for each one's acknowledgement before the next.

use std::io::{Read, Write};
use std::time::Duration;

use super::{connect, is_timeout};
use crate::error::{Error, Result};

/// One parsed packet.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Packet {
    /// The header (`TMSCT`, `CPERR`, `TMSTA`, ...).
    pub header: String,
    /// The data field.
    pub data: String,
}

/// The XOR of `bytes` (the listen node's checksum).
pub fn checksum(bytes: &[u8]) -> u8 {
    bytes.iter().fold(0, |a, b| a ^ b)
}

/// Parses one packet (with or without its CR LF), checking its length and checksum.
///
/// # Errors
/// A message saying what is wrong (no `$`, no `,*`, a bad length or checksum).
pub fn parse_packet(text: &str) -> std::result::Result<Packet, String> {
    let t = text.strip_suffix("\r\n").unwrap_or(text);
    let t = t.strip_prefix('$').ok_or_else(|| format!("`{t}` does not start with `$`"))?;
    let star = t.rfind(",*").ok_or_else(|| format!("`{t}` has no `,*<checksum>`"))?;
    let body = &t[..=star];
    let hex = &t[star + 2..];
    let cs = u8::from_str_radix(hex, 16).ok().filter(|_| hex.len() == 2);
    let cs = cs.ok_or_else(|| format!("checksum `{hex}` is not two hex digits"))?;
    let computed = checksum(body.as_bytes());
    if cs != computed {
        return Err(format!("checksum {cs:02X} does not match the packet's {computed:02X}"));
    }
    let (header, rest) = body.split_once(',').ok_or("no header")?;
    let (len, data) = rest.split_once(',').ok_or("no length")?;
    let data = data.strip_suffix(',').unwrap_or(data);
    let len: usize = len.parse().map_err(|_| format!("length `{len}` is not a number"))?;
    if len != data.len() {
        return Err(format!("length {len} but the data has {} bytes", data.len()));
    }
    Ok(Packet { header: header.to_string(), data: data.to_string() })
}

/// Splits a packets file (as [`crate::pierce::techman_packets`] writes it) into its packets,
/// each with its CR LF, checking each. A packet's end is found from its length field (a script's
/// lines are joined by CR LF inside the data).
///
/// # Errors
/// [`Error::Invalid`] about the packet (1-based) that does not parse.
pub fn split_packets(text: &str) -> Result<Vec<String>> {
    let mut out = Vec::new();
    let mut rest = text;
    while !rest.is_empty() {
        let k = out.len() + 1;
        let bad = |m: String| Error::invalid(format!("Techman packet {k}"), m);
        // $HEADER,LEN,DATA,*HH CR LF
        let mut fields = rest.splitn(3, ',');
        let (Some(header), Some(len), Some(_)) = (fields.next(), fields.next(), fields.next()) else {
            return Err(bad("not `$<header>,<length>,<data>,*<checksum>`".into()));
        };
        let digits = len.len();
        let len: usize = len.parse().map_err(|_| bad(format!("length `{len}` is not a number")))?;
        let end = header.len() + 1 + digits + 1 + len + ",*HH\r\n".len();
        let packet = rest.get(..end).ok_or_else(|| bad(format!("shorter than its length {len} says")))?;
        if !packet.ends_with("\r\n") {
            return Err(bad("does not end with `,*<checksum>` and CR LF where its length says".into()));
        }
        parse_packet(packet).map_err(bad)?;
        out.push(packet.to_string());
        rest = &rest[end..];
    }
    if out.is_empty() {
        return Err(Error::invalid("Techman packets", "none to send"));
    }
    Ok(out)
}

fn cperr_meaning(code: &str) -> &'static str {
    match code {
        "01" => "packet error",
        "02" => "checksum error",
        "03" => "header error",
        "04" => "packet data error",
        "F1" => "not in a listen node (start the TMflow project at its Listen node)",
        _ => "unknown error code",
    }
}

/// Per packet sent: its id and the listen node's answer data.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TechmanReply {
    /// (id, answer data) per packet, in order.
    pub acknowledged: Vec<(String, String)>,
}

/// Reads one packet (up to CR LF) from the stream.
fn read_packet(stream: &mut impl Read, pending: &mut Vec<u8>) -> std::io::Result<Option<String>> {
    loop {
        if let Some(end) = pending.windows(2).position(|w| w == b"\r\n") {
            let line: Vec<u8> = pending.drain(..end + 2).collect();
            return Ok(Some(String::from_utf8_lossy(&line).into_owned()));
        }
        let mut buf = [0u8; 1024];
        let n = stream.read(&mut buf)?;
        if n == 0 {
            return Ok(None);
        }
        pending.extend_from_slice(&buf[..n]);
        if pending.len() > 1 << 20 {
            return Err(std::io::Error::other("a reply of more than 1 MB without CR LF"));
        }
    }
}

/// Sends `packets` (a packets file: [`split_packets`]) to the listen node at `host:port`, each
/// after the previous one's `OK`.
///
/// # Errors
/// [`Error::Invalid`] for a malformed packets file; [`Error::Robot`] naming the packet's id when
/// the connection fails, no answer arrives within `timeout`, the connection closes, the answer is
/// malformed (bad checksum or length), a `$CPERR` (with its code's meaning) or an `ERROR` comes
/// back, or the answer is for another id.
pub fn send_packets(host: &str, port: u16, packets: &str, timeout: Duration) -> Result<TechmanReply> {
    let list = split_packets(packets)?;
    let address = format!("{host}:{port}");
    let mut stream = connect(host, port, timeout)?;
    let mut pending = Vec::new();
    let mut reply = TechmanReply { acknowledged: Vec::new() };
    for (k, p) in list.iter().enumerate() {
        let sent = parse_packet(p).map_err(|m| Error::invalid(format!("Techman packet {}", k + 1), m))?;
        let id = sent.data.split(',').next().unwrap_or("").to_string();
        let what = format!("packet {} of {} ({} id {id})", k + 1, list.len(), sent.header);
        stream
            .write_all(p.as_bytes())
            .and_then(|()| stream.flush())
            .map_err(|e| Error::robot(&address, format!("sending {what}: {e}")))?;
        loop {
            let answer = match read_packet(&mut stream, &mut pending) {
                Ok(Some(a)) => a,
                Ok(None) => {
                    return Err(Error::robot(
                        &address,
                        format!("the listen node closed the connection before answering {what}"),
                    ));
                }
                Err(e) if is_timeout(&e) => {
                    return Err(Error::robot(
                        &address,
                        format!(
                            "no answer to {what} within {:.1} s (no acknowledgement: stopped)",
                            timeout.as_secs_f64()
                        ),
                    ));
                }
                Err(e) => return Err(Error::robot(&address, format!("reading the answer to {what}: {e}"))),
            };
            let a = parse_packet(&answer).map_err(|m| {
                Error::robot(&address, format!("malformed answer to {what}: {m} (`{}`)", answer.trim_end()))
            })?;
            match a.header.as_str() {
                "CPERR" => {
                    return Err(Error::robot(
                        &address,
                        format!("negative acknowledgement of {what}: $CPERR {} ({})", a.data, cperr_meaning(&a.data)),
                    ));
                }
                "TMSCT" => {
                    let (their_id, status) = a.data.split_once(',').unwrap_or((a.data.as_str(), ""));
                    if their_id != id {
                        return Err(Error::robot(
                            &address,
                            format!("answer for id `{their_id}` while waiting for {what}"),
                        ));
                    }
                    if status != "OK" {
                        return Err(Error::robot(&address, format!("negative acknowledgement of {what}: {status}")));
                    }
                    reply.acknowledged.push((id.clone(), a.data.clone()));
                    break;
                }
                // status packets the listen node may send in between
                _ => continue,
            }
        }
    }
    Ok(reply)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn packets_parse_back_and_bad_ones_are_named() {
        let p = crate::pierce::tmsct_packet("1", "var_i++");
        assert_eq!(parse_packet(&p), Ok(Packet { header: "TMSCT".into(), data: "1,var_i++".into() }));
        assert!(parse_packet("$TMSCT,9,1,var_i++,*07\r\n").expect_err("refused").contains("checksum"));
        assert!(parse_packet("$CPERR,2,02,*4A").is_ok());
        let bad = format!("{p}$TMSCT,3,1,x,*00\r\n");
        assert!(split_packets(&bad).expect_err("refused").to_string().contains("packet 2"));
        let two = format!("{}{p}", crate::pierce::tmsct_packet("a1", "x = 1\r\ny = 2"));
        assert_eq!(split_packets(&two).expect("two").len(), 2);
    }
}
