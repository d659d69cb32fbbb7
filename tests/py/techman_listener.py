"""A stand-in for a Techman controller's listen node (TCP) on 127.0.0.1, written from Techman's
"Expression Editor and Listen Node" manual (TMflow 1.84 edition, Listen Node chapter: the packet
format pp. 230-231, $TMSCT pp. 232-233, $TMSTA pp. 234-237, $CPERR pp. 238-239), not from awl's code.

    python techman_listener.py MODE RECEIVED_FILE

Prints the port (first line of stdout), accepts one client and reads packets
`$<header>,<length>,<data>,*<checksum>` CR LF. For each it checks the framing independently: the
`$`, the header (TMSCT or TMSTA, case-sensitive), the length (the UTF-8 bytes of <data>, decimal or
0x hex or 0b binary), the checksum (XOR of every byte between `$` and `*`, two upper-case hex
digits), for TMSCT the id (alphanumeric, before the first comma of <data>). A packet that fails gets
`$CPERR,2,<code>,*<cs>` as the manual's examples do: 01 packet error (no `$`, no `,*HH` CR LF, a
length that is not a byte count or not the data's), 02 checksum error, 03 header error, 04 packet
data error (a bad id, an unknown TMSTA subcommand). `$TMSTA` 00 is answered
`$TMSTA,<len>,00,true,Listen1,*<cs>` (in the listen node), 01 `<tag>` with `01,<tag>,none`.
Writes every byte received to RECEIVED_FILE and a JSON verdict as the last stdout line:
{"packets": n, "checksums_verified": n, "errors": [...], "ids": [...], "scripts": [...]} (the TMSCT
packets' ids and scripts).

MODE: `ok`      answers `$TMSCT,<len>,<id>,OK,*<cs>` to each valid packet;
      `listen1_warn`  first sends the node's entry message `$TMSCT,9,0,Listen1,*4C` (id 0, as the
                manual's listen node does on entering it), then answers `<id>,OK;1` (taken, a warning
                on script line 1) to the first packet and OK to the others;
      `nack2`   answers OK to the first packet and `$CPERR,2,04,*..` (packet data error) to the second;
      `error1`  answers `<id>,ERROR;1` (a script error on line 1) to the first packet;
      `silent`  never answers (the client must time out).
"""

import json
import socket
import sys


def cs(body: bytes) -> str:
    x = 0
    for b in body:
        x ^= b
    return "%02X" % x


def packet(header: str, data: str) -> bytes:
    body = f"{header},{len(data.encode())},{data},".encode()
    return b"$" + body + b"*" + cs(body).encode() + b"\r\n"


def byte_count(field: bytes):
    """The Length field (decimal, 0x hex, 0b binary), or None."""
    text = field.decode("latin-1").lower()
    base, digits = (16, text[2:]) if text.startswith("0x") else (2, text[2:]) if text.startswith("0b") else (10, text)
    if not digits or not all(c in "0123456789abcdef"[:base] for c in digits):
        return None
    return int(digits, base)


def check(raw: bytes):
    """(error code or None, message, header, data)"""
    if not raw.startswith(b"$"):
        return "01", "no $", None, None
    star = raw.rfind(b",*")
    if star < 0 or not raw.endswith(b"\r\n") or len(raw) != star + 6:
        return "01", "no ,*HH CR LF ending", None, None
    body = raw[1 : star + 1]
    given = raw[star + 2 : star + 4].decode("latin-1")
    if given != cs(body):
        return "02", f"checksum {given} != {cs(body)}", None, None
    parts = body[:-1].split(b",", 2)
    if len(parts) < 3 or parts[0] not in (b"TMSCT", b"TMSTA"):
        return "03", f"header {parts[0]!r}", None, None
    length = byte_count(parts[1])
    if length is None:
        return "01", f"length {parts[1]!r} is not a byte count", None, None
    data = parts[2]
    if length != len(data):
        return "01", f"length {length} != {len(data)}", None, None
    header = parts[0].decode()
    if header == "TMSCT":
        ident = data.decode("latin-1").partition(",")[0]
        if not ident.isalnum():
            return "04", f"id {ident!r} not alphanumeric", None, None
    else:
        subcmd = data.decode("latin-1").partition(",")[0]
        if subcmd not in ("00", "01"):
            return "04", f"TMSTA subcommand {subcmd!r}", None, None
    return None, "", header, data.decode("utf-8", "replace")


def main() -> int:
    mode, out_path = sys.argv[1], sys.argv[2]
    server = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    server.bind(("127.0.0.1", 0))
    server.listen(1)
    print(server.getsockname()[1], flush=True)
    server.settimeout(20)
    conn, _ = server.accept()
    conn.settimeout(5)
    if mode == "listen1_warn":
        conn.sendall(packet("TMSCT", "0,Listen1"))
    received = b""
    pending = b""
    verdict = {"packets": 0, "checksums_verified": 0, "errors": [], "ids": [], "scripts": []}
    try:
        while True:
            chunk = conn.recv(65536)
            if not chunk:
                break
            received += chunk
            pending += chunk
            while b"\r\n" in pending:
                # a packet ends at the CR LF after its ,*HH (scripts hold CR LF of their own)
                star = pending.find(b",*")
                if star < 0 or len(pending) < star + 6:
                    break
                raw, pending = pending[: star + 6], pending[star + 6 :]
                verdict["packets"] += 1
                code, message, header, data = check(raw)
                if code is not None:
                    verdict["errors"].append(f"packet {verdict['packets']}: {message}")
                    conn.sendall(packet("CPERR", code))
                    continue
                verdict["checksums_verified"] += 1
                if header == "TMSTA":
                    subcmd, _, rest = data.partition(",")
                    answer = "00,true,Listen1" if subcmd == "00" else f"01,{rest},none"
                    conn.sendall(packet("TMSTA", answer))
                    continue
                ident, _, script = data.partition(",")
                verdict["ids"].append(ident)
                verdict["scripts"].append(script)
                n = verdict["packets"]
                if mode == "silent":
                    continue
                if mode == "nack2" and n == 2:
                    conn.sendall(packet("CPERR", "04"))
                elif mode == "error1" and n == 1:
                    conn.sendall(packet("TMSCT", f"{ident},ERROR;1"))
                elif mode == "listen1_warn" and n == 1:
                    conn.sendall(packet("TMSCT", f"{ident},OK;1"))
                else:
                    conn.sendall(packet("TMSCT", f"{ident},OK"))
    except socket.timeout:
        pass
    conn.close()
    with open(out_path, "wb") as f:
        f.write(received)
    print(json.dumps(verdict))
    return 0


if __name__ == "__main__":
    sys.exit(main())
