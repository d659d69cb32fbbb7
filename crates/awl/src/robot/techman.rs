//! Techman listen-node packets sent to a TM controller (TCP port 5890), as Techman's "Expression
//! Editor and Listen Node" manual (the edition for TMflow software version 1.84; its Listen Node chapter:
//! "Communication Protocol" pp. 230-231, `$TMSCT` pp. 232-233, `$TMSTA` pp. 234-237, `$CPERR`
//! pp. 238-239) defines them. Read through its public copies (the 1.80 edition at vdocuments.net,
//! "Expression Editor and Listen Node", I848-E-03, whose opening pages only were at hand) and a
//! page-by-page public summary of the 1.84 edition quoting its example packets; the example packets
//! checked below are the manual's.
//!
//! A packet is `$<header>,<length>,<data>,*<checksum>` and CR LF: `<length>` is the UTF-8 byte count
//! of `<data>` (decimal, or `0x` hexadecimal, or `0b` binary: `0x100` is 256 bytes), `<checksum>`
//! the XOR of every byte between `$` and `*`, two upper-case hex digits
//! ([`crate::pierce::tmsct_packet`] writes them). For a `$TMSCT` packet (data `<id>,<script>`, the
//! id alphanumeric) the listen node answers `$TMSCT` with data `<id>,OK` when it took the script,
//! `<id>,OK;2;3` when it took it with warnings on those script lines, `<id>,ERROR;1;2;3` when the
//! script has errors on those lines (nothing of it runs), or `$CPERR` with an error code (data `00`
//! success, `01` packet error, `02` checksum error, `03` header error, `04` packet data error, `F1`
//! not in a listen node) when the packet itself was bad. On entering the Listen node it sends its
//! "Send Message" to the connected clients with id 0 (`$TMSCT,9,0,Listen1,*4C`), and it may send
//! `$TMSTA` status packets (e.g. `$TMSTA,10,01,08,true,*6D`: queue tag 8 done) at any time.
//! [`send_packets`] sends the packets one at a time and waits for each one's acknowledgement before
//! the next.

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

/// A packet's length field: decimal, `0x` hexadecimal or `0b` binary (the manual's "Length").
///
/// # Errors
/// A message naming the field when it is none of those.
pub fn parse_length(field: &str) -> std::result::Result<usize, String> {
    let lower = field.to_ascii_lowercase();
    let parsed = if let Some(hex) = lower.strip_prefix("0x") {
        usize::from_str_radix(hex, 16)
    } else if let Some(bin) = lower.strip_prefix("0b") {
        usize::from_str_radix(bin, 2)
    } else {
        lower.parse::<usize>()
    };
    parsed.map_err(|_| format!("length `{field}` is not a decimal, 0x hex or 0b binary byte count"))
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
    let len = parse_length(len)?;
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
        let len = parse_length(len).map_err(bad)?;
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
        "00" => "success",
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
    /// (id, the script lines with warnings, e.g. `2;3`) per packet taken with warnings (`OK;2;3`).
    pub warnings: Vec<(String, String)>,
    /// The listen node's message on entering it (id 0, its "Send Message"), when one came.
    pub listen_node: Option<String>,
}

/// What a `$TMSCT` answer's status (the data after `<id>,`) says: `Ok(None)` taken, `Ok(Some(lines))`
/// taken with warnings on those script lines, `Err(status)` refused (`ERROR;<lines>` or anything else).
pub fn tmsct_status(status: &str) -> std::result::Result<Option<&str>, &str> {
    match status.strip_prefix("OK") {
        Some("") => Ok(None),
        Some(rest) => rest.strip_prefix(';').filter(|l| !l.is_empty()).map(Some).ok_or(status),
        None => Err(status),
    }
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
    let mut reply = TechmanReply { acknowledged: Vec::new(), warnings: Vec::new(), listen_node: None };
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
                    if their_id == "0" && id != "0" {
                        // the listen node's message on entering it, not an answer
                        reply.listen_node = Some(status.to_string());
                        continue;
                    }
                    if their_id != id {
                        return Err(Error::robot(
                            &address,
                            format!("answer for id `{their_id}` while waiting for {what}"),
                        ));
                    }
                    match tmsct_status(status) {
                        Ok(warned) => {
                            if let Some(lines) = warned {
                                reply.warnings.push((id.clone(), lines.to_string()));
                            }
                        }
                        Err(refused) => {
                            return Err(Error::robot(
                                &address,
                                format!("negative acknowledgement of {what}: {refused}"),
                            ));
                        }
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

    /// The manual's example packets (Listen Node chapter, pp. 230-239): each parses with its
    /// length and checksum, and our writer gives the same bytes for the ones a client sends.
    #[test]
    fn the_manuals_example_packets_parse_and_are_written_byte_for_byte() {
        let examples = [
            ("$TMSCT,5,10,OK,*6D\r\n", "TMSCT", "10,OK"),
            ("$TMSCT,9,0,Listen1,*4C\r\n", "TMSCT", "0,Listen1"),
            ("$TMSCT,4,1,OK,*5C\r\n", "TMSCT", "1,OK"),
            ("$TMSCT,8,2,OK;2;3,*52\r\n", "TMSCT", "2,OK;2;3"),
            ("$TMSCT,13,3,ERROR;1;2;3,*3F\r\n", "TMSCT", "3,ERROR;1;2;3"),
            ("$TMSCT,25,1,ChangeBase(\"RobotBase\"),*08\r\n", "TMSCT", "1,ChangeBase(\"RobotBase\")"),
            ("$TMSTA,2,00,*41\r\n", "TMSTA", "00"),
            ("$TMSTA,9,00,false,,*37\r\n", "TMSTA", "00,false,"),
            ("$TMSTA,15,00,true,Listen1,*79\r\n", "TMSTA", "00,true,Listen1"),
            ("$TMSTA,10,01,08,true,*6D\r\n", "TMSTA", "01,08,true"),
            ("$TMSTA,5,01,15,*6F\r\n", "TMSTA", "01,15"),
            ("$TMSTA,10,01,15,none,*7D\r\n", "TMSTA", "01,15,none"),
            ("$TMSTA,14,90,Hello World,*73\r\n", "TMSTA", "90,Hello World"),
            ("$CPERR,2,01,*49\r\n", "CPERR", "01"),
            ("$CPERR,2,02,*4A\r\n", "CPERR", "02"),
            ("$CPERR,2,03,*4B\r\n", "CPERR", "03"),
            ("$CPERR,2,04,*4C\r\n", "CPERR", "04"),
            ("$CPERR,2,F1,*3F\r\n", "CPERR", "F1"),
        ];
        for (text, header, data) in examples {
            assert_eq!(parse_packet(text), Ok(Packet { header: header.into(), data: data.into() }), "{text}");
        }
        let multi = "ChangeBase(\"RobotBase\")\r\nChangeTCP(\"NOTOOL\")\r\nChangeLoad(10.1)";
        assert_eq!(crate::pierce::tmsct_packet("2", multi), format!("$TMSCT,64,2,{multi},*68\r\n"));
        let local = "int var_i = 100\r\nvar_i = 1000\r\nvar_i++";
        assert_eq!(crate::pierce::tmsct_packet("3", local), format!("$TMSCT,40,3,{local},*5A\r\n"));
        assert_eq!(crate::pierce::tmsct_packet("2", "ScriptExit(0)"), "$TMSCT,15,2,ScriptExit(0),*55\r\n");
        assert_eq!(
            crate::pierce::tmsct_packet("2", "StopAndClearBuffer(0)"),
            "$TMSCT,23,2,StopAndClearBuffer(0),*55\r\n"
        );
        assert_eq!(crate::pierce::tmsct_packet("2", "Techman Robot"), "$TMSCT,15,2,Techman Robot,*57\r\n");
        // the manual's bad packets: a wrong checksum, a negative length
        assert!(parse_packet("$TMSCT,25,1,ChangeBase(\"RobotBase\"),*09\r\n").expect_err("cs").contains("checksum"));
        assert!(parse_packet("$TMSCT,-100,1,ChangeBase(\"RobotBase\"),*13\r\n").expect_err("len").contains("length"));
        // lengths in hex and binary
        assert_eq!(parse_length("0x100"), Ok(256));
        assert_eq!(parse_length("0b100"), Ok(4));
        assert_eq!(parse_length("100"), Ok(100));
        assert!(parse_length("-100").is_err() && parse_length("0xZ").is_err());
        // the answers' statuses
        assert_eq!(tmsct_status("OK"), Ok(None));
        assert_eq!(tmsct_status("OK;2;3"), Ok(Some("2;3")));
        assert_eq!(tmsct_status("ERROR;1;2;3"), Err("ERROR;1;2;3"));
        assert_eq!(tmsct_status("OK;"), Err("OK;"));
        assert_eq!(tmsct_status("OKAY"), Err("OKAY"));
    }

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
