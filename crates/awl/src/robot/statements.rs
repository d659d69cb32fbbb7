//! The statements awl's programs are made of, recognised by parsing, not by the writers: every
//! line of a URScript program ([`check_urscript_statements`]) and every script line of a Techman
//! packet ([`check_techman_statements`]) must be one of them. `awl send` checks both before a byte
//! leaves, so no program it sends carries a statement awl does not write, whatever plan.json says.
//!
//! URScript: `def awl_pierce():` (or `def awl_views():`, the views of `awl plan-views`), `end`, and
//! indented by two spaces: a comment `# ` of printable ASCII, `set_tcp(p[6 numbers])`,
//! `movej([6 numbers], a=N, v=N)`, `movel(p[6 numbers], a=N, v=N)`, `sleep(N)`.
//! Techman: `ChangeBase("RobotBase")`, `ChangeTCP(6 numbers)`, `PTP("JPP",6 numbers,N,N,0,true)`,
//! `Line("CAP",6 numbers,N,N,0,true)`, `ScriptExit()`. A number is a finite decimal: an optional
//! `-`, digits, optionally `.` and digits.

use crate::error::{Error, Result};

/// Whether `s` is a finite decimal number as the writers print them.
fn is_number(s: &str) -> bool {
    let digits = s.strip_prefix('-').unwrap_or(s);
    let (whole, fraction) = digits.split_once('.').unwrap_or((digits, "0"));
    !whole.is_empty()
        && !fraction.is_empty()
        && whole.bytes().all(|b| b.is_ascii_digit())
        && fraction.bytes().all(|b| b.is_ascii_digit())
}

/// Whether `s` is `n` numbers separated by `separator`.
fn numbers(s: &str, n: usize, separator: &str) -> bool {
    let parts: Vec<&str> = s.split(separator).collect();
    parts.len() == n && parts.iter().all(|p| is_number(p))
}

/// `s` with `prefix` and `suffix` taken off, when it has both.
fn between<'a>(s: &'a str, prefix: &str, suffix: &str) -> Option<&'a str> {
    s.strip_prefix(prefix)?.strip_suffix(suffix)
}

/// Whether `s` is `a=N, v=N`.
fn speeds(s: &str) -> bool {
    between(s, "a=", "").and_then(|r| r.split_once(", v=")).is_some_and(|(a, v)| is_number(a) && is_number(v))
}

/// Whether `line` (without its two-space indent) is one of awl's URScript statements.
fn ur_statement(line: &str) -> bool {
    if let Some(comment) = line.strip_prefix("# ") {
        return comment.bytes().all(|b| (b' '..=b'~').contains(&b));
    }
    if let Some(pose) = between(line, "set_tcp(p[", "])") {
        return numbers(pose, 6, ", ");
    }
    if let Some(seconds) = between(line, "sleep(", ")") {
        return is_number(seconds);
    }
    let motion = |prefix: &str, close: &str| {
        between(line, prefix, ")")
            .and_then(|r| r.split_once(close))
            .is_some_and(|(v, rest)| numbers(v, 6, ", ") && rest.strip_prefix(", ").is_some_and(speeds))
    };
    motion("movej([", "]") || motion("movel(p[", "]")
}

/// Checks that every line of `program` is one of awl's URScript statements (module docs).
///
/// # Errors
/// [`Error::Invalid`] about `URScript program` naming the first line that is not, and its number.
pub fn check_urscript_statements(program: &str) -> Result<()> {
    let lines: Vec<&str> = program.split('\n').collect();
    let last = lines.len().saturating_sub(1);
    for (i, line) in lines.iter().enumerate() {
        let ok = match i {
            0 => *line == "def awl_pierce():" || *line == "def awl_views():",
            _ if i == last => line.is_empty(),
            _ if i + 1 == last => *line == "end",
            _ => line.strip_prefix("  ").is_some_and(ur_statement),
        };
        if !ok {
            return Err(Error::invalid(
                "URScript program",
                format!("line {} is not a statement awl writes: `{}`; nothing is sent", i + 1, line.escape_debug()),
            ));
        }
    }
    Ok(())
}

/// Whether `line` is one of awl's Techman script lines.
fn tm_statement(line: &str) -> bool {
    if line == "ChangeBase(\"RobotBase\")" || line == "ScriptExit()" {
        return true;
    }
    if let Some(v) = between(line, "ChangeTCP(", ")") {
        return numbers(v, 6, ",");
    }
    let motion = |prefix: &str| {
        between(line, prefix, ",0,true)").is_some_and(|v| {
            let parts: Vec<&str> = v.split(',').collect();
            parts.len() == 8 && parts.iter().all(|p| is_number(p))
        })
    };
    motion("PTP(\"JPP\",") || motion("Line(\"CAP\",")
}

/// Checks that every script line of every packet in `packets` (each packet's data after its id,
/// lines joined by CR LF) is one of awl's Techman statements (module docs).
///
/// # Errors
/// [`Error::Invalid`] about the Techman packet (1-based) and its line that is not.
pub fn check_techman_statements(packets: &[String]) -> Result<()> {
    for (k, p) in packets.iter().enumerate() {
        let packet = crate::robot::techman::parse_packet(p)
            .map_err(|m| Error::invalid(format!("Techman packet {}", k + 1), m))?;
        let script = packet.data.split_once(',').map_or("", |(_, s)| s);
        for (i, line) in script.split("\r\n").enumerate() {
            if !tm_statement(line) {
                return Err(Error::invalid(
                    format!("Techman packet {}", k + 1),
                    format!(
                        "script line {} is not a statement awl writes: `{}`; nothing is sent",
                        i + 1,
                        line.escape_debug()
                    ),
                ));
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_awls_statements_pass() {
        let good = "def awl_pierce():\n  # awl pierce: 1 of 1 target(s) from a/b\n  set_tcp(p[0.000000, 0.000000, \
                    0.150000, 0.000000, 0.000000, 0.000000])\n  movej([0.1, -1.2, 1.4, -1.8, -1.57, 0.4], a=1, v=0.5)\n  \
                    movel(p[0.45, 0.15, 0.11, 3.141593, 0.0, 0.0], a=0.5, v=0.02)\nend\n";
        check_urscript_statements(good).expect("awl's own");
        // the views program of awl plan-views: its header and the wait at each view
        let views = good.replace("def awl_pierce", "def awl_views").replace("end\n", "  sleep(2.000)\nend\n");
        check_urscript_statements(&views).expect("awl's own views program");
        for bad in [
            good.replace("# awl pierce", "# x\n  movej([0,0,0,0,0,0], a=3, v=3)\n  #"),
            good.replace("# awl", "# \u{202e}awl"),
            good.replace("# awl", "#\rawl"),
            good.replace("a=0.5, v=0.02", "a=0.5, v=0.02, r=0"),
            good.replace("0.45, 0.15", "nan, 0.15"),
            good.replace("0.45, 0.15", "1e3, 0.15"),
            good.replace("0.45, 0.15, 0.11, 3.141593, 0.0, 0.0", "0.45, 0.15, 0.11, 3.141593, 0.0"),
            good.replace("  movej", "  popup(\"x\")\n  movej"),
            good.replace("def awl_pierce", "def other"),
            good.replace("end\n", "end\nawl_pierce()\n"),
            good.replace("end\n", "  sleep(x)\nend\n"),
            good.replace("end\n", "  sleep(-)\nend\n"),
            good.replace("end\n", "  sleep(2.0); popup(\"x\")\nend\n"),
        ] {
            let e = check_urscript_statements(&bad).expect_err(&bad).to_string();
            assert!(e.contains("is not a statement awl writes"), "{e}");
        }
        let tm = crate::pierce::tmsct_packet(
            "awl0",
            "ChangeBase(\"RobotBase\")\r\nLine(\"CAP\",450.000,150.000,110.000,180.0000,0.0000,0.0000,20,40,0,true)",
        );
        check_techman_statements(&[tm.clone(), crate::pierce::tmsct_packet("awlexit", "ScriptExit()")])
            .expect("awl's own");
        let bad = crate::pierce::tmsct_packet("awl0", "ChangeBase(\"RobotBase\")\r\nQueueTag(1)");
        let e = check_techman_statements(&[tm, bad]).expect_err("QueueTag").to_string();
        assert!(e.contains("packet 2") && e.contains("script line 2") && e.contains("QueueTag"), "{e}");
    }
}
