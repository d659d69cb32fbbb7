"""A stand-in for a Universal Robots controller's primary / secondary client interface on
127.0.0.1, written from UR's documents (script manual "Connecting to URControl"; the "Primary and
Secondary Interfaces" guide), not from awl's code.

    python ur_listener.py MODE RECEIVED_FILE

Prints the port it listens on (first line of stdout), accepts one client, reads the program and
checks its framing as the controller requires: extended ASCII, lines ended by "\\n", the first line a
`def` or `sec` in the first column, every other line indented by at least one white space, the
last line `end` in the first column. Writes the bytes received to RECEIVED_FILE and a JSON verdict
on the last line of stdout: {"bytes": n, "errors": [...], "sent_state": bool}.

MODE: `state`  answers with one robot-state message once the program is complete (a 4-byte
               big-endian length, the type 16 = ROBOT_STATE, one sub-package), as the controller
               streams its state;
      `silent` answers nothing (the client must time out).
"""

import json
import socket
import struct
import sys


def check_program(data: bytes) -> list:
    errors = []
    try:
        text = data.decode("latin-1")
    except UnicodeDecodeError as e:  # pragma: no cover - latin-1 decodes every byte
        return [f"not extended ASCII: {e}"]
    if not text.endswith("\n"):
        errors.append("the program does not end with a newline")
    lines = text.split("\n")[:-1] if text.endswith("\n") else text.split("\n")
    if not lines:
        return errors + ["empty program"]
    if not (lines[0].startswith("def ") or lines[0].startswith("sec ")):
        errors.append(f"line 1 is not a def/sec in the first column: {lines[0]!r}")
    if lines[-1] != "end":
        errors.append(f"the last line is not `end` in the first column: {lines[-1]!r}")
    for i, line in enumerate(lines[1:-1], start=2):
        if line and not line[0] in " \t":
            errors.append(f"line {i} is not indented: {line!r}")
    return errors


def state_message() -> bytes:
    # one sub-package: length (4 bytes), type 0 (robot mode data), then its payload
    sub_payload = bytes(40)
    sub = struct.pack(">iB", 5 + len(sub_payload), 0) + sub_payload
    body = struct.pack(">B", 16) + sub + bytes(60)
    return struct.pack(">i", 4 + len(body)) + body


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
    sent_state = False
    try:
        while True:
            chunk = conn.recv(65536)
            if not chunk:
                break
            received += chunk
            if (received.endswith(b"\nend\n") or received == b"end\n") and not sent_state:
                if mode == "state":
                    conn.sendall(state_message())
                    sent_state = True
    except socket.timeout:
        pass
    except ConnectionResetError:
        # the client closed with state unread (it reads what it needs): the end of the connection
        pass
    conn.close()
    with open(out_path, "wb") as f:
        f.write(received)
    print(json.dumps({"bytes": len(received), "errors": check_program(received), "sent_state": sent_state}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
