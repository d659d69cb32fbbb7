"""A stand-in for a Techman controller's listen node (TCP) on 127.0.0.1, written from Techman's
"Expression Editor and Listen Node" manual, not from awl's code.

    python techman_listener.py MODE RECEIVED_FILE

Prints the port (first line of stdout), accepts one client and reads packets
`$<header>,<length>,<data>,*<checksum>` CR LF. For each it checks the framing independently: the
`$`, the header TMSCT, the length (bytes of <data>), the checksum (XOR of every byte between `$` and
`*`, two upper-case hex digits), the id (alphanumeric, before the first comma of <data>). A packet
that fails gets `$CPERR,2,<code>,*<cs>` (01 packet, 02 checksum, 03 header, 04 packet data error).
Writes every byte received to RECEIVED_FILE and a JSON verdict as the last stdout line:
{"packets": n, "checksums_verified": n, "errors": [...], "ids": [...], "scripts": [...]}.

MODE: `ok`      answers `$TMSCT,<len>,<id>,OK,*<cs>` to each valid packet;
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


def check(raw: bytes):
    """(error code or None, message, id, script)"""
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
    if len(parts) < 3 or parts[0] != b"TMSCT":
        return "03", f"header {parts[0]!r}", None, None
    try:
        length = int(parts[1])
    except ValueError:
        return "04", "length not a number", None, None
    data = parts[2]
    if length != len(data):
        return "04", f"length {length} != {len(data)}", None, None
    ident, _, script = data.decode("latin-1").partition(",")
    if not ident.isalnum():
        return "04", f"id {ident!r} not alphanumeric", None, None
    return None, "", ident, script


def main() -> int:
    mode, out_path = sys.argv[1], sys.argv[2]
    server = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    server.bind(("127.0.0.1", 0))
    server.listen(1)
    print(server.getsockname()[1], flush=True)
    server.settimeout(20)
    conn, _ = server.accept()
    conn.settimeout(5)
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
                code, message, ident, script = check(raw)
                if code is not None:
                    verdict["errors"].append(f"packet {verdict['packets']}: {message}")
                    conn.sendall(packet("CPERR", code))
                    continue
                verdict["checksums_verified"] += 1
                verdict["ids"].append(ident)
                verdict["scripts"].append(script)
                n = verdict["packets"]
                if mode == "silent":
                    continue
                if mode == "nack2" and n == 2:
                    conn.sendall(packet("CPERR", "04"))
                elif mode == "error1" and n == 1:
                    conn.sendall(packet("TMSCT", f"{ident},ERROR;1"))
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
