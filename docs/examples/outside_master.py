#!/usr/bin/env python3
"""A minimal outside master for h4-teleop's slave, written from docs/wire.md alone (protocol 3).

Needs the `eclipse-zenoh` package (pip install eclipse-zenoh==1.10.2). Start a slave that
listens, e.g.

    h4-slave run --transport zenoh --zenoh-listen tcp/127.0.0.1:7461 --watchdog-ms 200 \
        --duration-s 10 --summary /tmp/slave.json

then `python3 docs/examples/outside_master.py tcp/127.0.0.1:7461`. It holds the arm where it
is for 1 s at 1 kHz, moves it 10 mm along x in 2 s (position mode, no contact), then sends one
of each kind of bad message, each followed by a good command, and prints how the slave's
feedback counts them (`rejected_count`). Every command echoes the newest feedback received
(docs/wire.md, "The command's echo"), so the slave measures its round trip: the slave's
summary shows it (`rtt_measured_p50_ms`, `round_trip_samples`), each bad message under its
reason (`gate.*`), and the one impossible echo this client sends on purpose in
`round_trip_echoes_refused` (that command itself is accepted). It prints the surface estimate
of the last feedback (`contact_state` 1, free space). Passivity: this master sends 0 in both
energy fields, which is enough for motion in free space (the slave will not push into a
contact without energy; docs/wire.md, "Passivity"). Checked against `h4-slave run` on
2026-12-08: every bad message rejected and counted, 0 commands acted on wrongly, the round
trip measured.
"""
import json
import random
import struct
import sys
import threading
import time

import zenoh

CMD = "<2sHBBHQQQ4d4ddddHHBBHQQ"  # docs/wire.md, "Command": 144 bytes
FB = "<2sHBBHQQQQQ4d4d4dddHHBBHII3d3dd"  # docs/wire.md, "Feedback": 232 bytes
VERSION = 3


def command(session, seq, pose, echo, mode=1, force_n=0.0, energy_in_j=0.0, version=VERSION,
            arm=0, reserved=0, header_reserved=0, body_len=128, flags=0):
    """One command; `echo` is (seq, send_time_ns) of the newest feedback, (0, 0) before any."""
    return struct.pack(CMD, b"H4", version, 1, header_reserved, body_len, session, seq,
                       time.monotonic_ns(), *pose, 0.0, 0.0, 0.0, 0.0, force_n, energy_in_j,
                       0.0, version, arm, mode, reserved, flags, echo[0], echo[1])


def parse_feedback(b):
    """The fields this client uses, or None for bytes that are not protocol 3 feedback."""
    if len(b) != struct.calcsize(FB):
        return None
    f = struct.unpack(FB, b)
    if (f[0] != b"H4" or f[1] != VERSION or f[2] != 2 or f[3] != 0 or f[4] != 216
            or f[24] != VERSION):
        return None
    return {"session_id": f[5], "seq": f[6], "send_time_ns": f[7], "echo_seq": f[8],
            "pose": f[10:14], "state": f[26], "contact_state": f[27], "fault_flags": f[28],
            "rejected_reasons": f[29], "rejected_count": f[30], "contact_point_mm": f[31:34],
            "contact_normal": f[34:37], "contact_stiffness_n_per_mm": f[37]}


def main():
    endpoint = sys.argv[1] if len(sys.argv) > 1 else "tcp/127.0.0.1:7461"
    newest, lock = {}, threading.Lock()

    def on_feedback(sample):
        f = parse_feedback(bytes(sample.payload.to_bytes()))
        if f is None:
            return
        with lock:
            # The newest: the highest seq of the slave's session (a new session replaces it).
            if (not newest or f["session_id"] != newest["session_id"]
                    or f["seq"] > newest["seq"]):
                newest.clear()
                newest.update(f)

    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    z = zenoh.open(conf)
    z.declare_subscriber("h4/0/feedback", on_feedback)
    pub = z.declare_publisher("h4/0/command")
    deadline = time.time() + 10
    while not newest and time.time() < deadline:
        time.sleep(0.01)
    if not newest:
        sys.exit("no feedback from the slave")

    def last():
        with lock:
            return dict(newest)

    def echo():
        f = last()
        return (f["seq"], f["send_time_ns"])

    home = last()["pose"]
    session = random.getrandbits(64) | 1  # any non-zero id, the same all run
    seq = 0

    def stream(seconds, pose_at):
        nonlocal seq
        n, t = int(seconds * 1000), time.perf_counter()
        for k in range(n):
            seq += 1
            pub.put(command(session, seq, pose_at(k / n), echo()))
            t += 0.001
            # 1 kHz (the slave's watchdog wants ≤ 20 ms gaps), sleeping, not spinning: a
            # spinning loop holds Python's GIL and starves the feedback callback, so the echo
            # would name feedback far older than the link's round trip (docs/wire.md, "The
            # command's echo").
            dt = t - time.perf_counter()
            if dt > 0:
                time.sleep(dt)

    stream(1.0, lambda a: home)
    goal = (home[0] + 10.0, home[1], home[2], home[3])
    stream(2.0, lambda a: (home[0] + 10.0 * a, home[1], home[2], home[3]))
    stream(0.5, lambda a: goal)
    print("moved to", [round(v, 3) for v in last()["pose"]], "state", last()["state"])

    def protocol2(s):
        # A protocol-2 master's command: 128 bytes, version 2, body length 112, no echo.
        return command(session, s, goal, (0, 0), version=2, body_len=112)[:128]

    bad = {
        "wrong_version (protocol 2)": protocol2,
        "wrong_arm": lambda s: command(session, s, goal, echo(), arm=7),
        "stale": lambda s: command(session, 1, goal, echo()),
        "out_of_range (pose)": lambda s: command(session, s, (1e6, 0.0, 0.0, 0.0), echo()),
        "out_of_range (force)": lambda s: command(session, s, goal, echo(), force_n=1e6),
        "implausible_energy": lambda s: command(session, s, goal, echo(), energy_in_j=1e6),
        "reserved_bits": lambda s: command(session, s, goal, echo(), reserved=1),
        "length_mismatch": lambda s: command(session, s, goal, echo(), body_len=100),
        "wild_seq": lambda s: command(session, 2**64 - 1, goal, echo()),
        "undecodable": lambda s: command(session, s, goal, echo())[:50],
    }
    for name, make in bad.items():
        before = last()["rejected_count"]
        pub.put(make(seq + 1))
        time.sleep(0.002)
        seq += 1
        pub.put(command(session, seq, goal, echo()))  # a good one: the watchdog stays fed
        time.sleep(0.015)
        print(f"{name:26s} rejected_count {before} -> {last()['rejected_count']}")
    # An echo of a feedback the slave has not sent: the command is accepted, the echo refused
    # (the slave's summary: round_trip_echoes_refused).
    seq += 1
    before = last()["rejected_count"]
    pub.put(command(session, seq, goal, (2**62, 1)))
    time.sleep(0.015)
    print(f"{'impossible echo':26s} rejected_count {before} -> {last()['rejected_count']}")
    stream(0.3, lambda a: goal)
    f = last()
    print("end at", [round(v, 3) for v in f["pose"]], "state", f["state"])
    print("surface: contact_state", f["contact_state"], "point_mm",
          [round(v, 3) for v in f["contact_point_mm"]], "normal",
          [round(v, 3) for v in f["contact_normal"]], "stiffness_n_per_mm",
          f["contact_stiffness_n_per_mm"])
    z.close()


if __name__ == "__main__":
    main()
