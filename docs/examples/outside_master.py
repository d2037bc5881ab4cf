#!/usr/bin/env python3
"""A minimal outside master for h4-teleop's slave, written from docs/wire.md alone.

Needs the `eclipse-zenoh` package (pip install eclipse-zenoh==1.10.2). Start a slave that
listens, e.g.

    h4-slave run --transport zenoh --zenoh-listen tcp/127.0.0.1:7461 --watchdog-ms 200 \
        --duration-s 10 --summary /tmp/slave.json

then `python3 docs/examples/outside_master.py tcp/127.0.0.1:7461`. It holds the arm where it
is for 1 s at 1 kHz, moves it 10 mm along x in 2 s (position mode, no contact), then sends one
of each kind of bad message, each followed by a good command, and prints how the slave's
feedback counts them (`rejected_count`). The slave's summary then shows each under its reason
(`gate.*`). Passivity: this master sends 0 in both energy fields, which is enough for motion
in free space (the slave will not push into a contact without energy; docs/wire.md,
"Passivity"). Checked against `h4-slave run` on 2026-12-03: every bad message rejected and
counted, 0 commands acted on wrongly.
"""
import json
import random
import struct
import sys
import threading
import time

import zenoh

CMD = "<2sHBBHQQQ4d4ddddHHBBH"  # docs/wire.md, "Command": 128 bytes
FB = "<2sHBBHQQQQQ4d4d4dddHHBBHII"  # docs/wire.md, "Feedback": 176 bytes


def command(session, seq, pose, mode=1, force_n=0.0, energy_in_j=0.0, version=2, arm=0,
            reserved=0, header_reserved=0, body_len=112, flags=0):
    return struct.pack(CMD, b"H4", version, 1, header_reserved, body_len, session, seq,
                       time.monotonic_ns(), *pose, 0.0, 0.0, 0.0, 0.0, force_n, energy_in_j,
                       0.0, version, arm, mode, reserved, flags)


def main():
    endpoint = sys.argv[1] if len(sys.argv) > 1 else "tcp/127.0.0.1:7461"
    feedback, lock = [], threading.Lock()

    def on_feedback(sample):
        b = bytes(sample.payload.to_bytes())
        if len(b) == struct.calcsize(FB):
            f = struct.unpack(FB, b)
            with lock:
                feedback.append({"echo_seq": f[8], "pose": f[10:14], "state": f[26],
                                 "rejected_count": f[30]})

    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    z = zenoh.open(conf)
    z.declare_subscriber("h4/0/feedback", on_feedback)
    pub = z.declare_publisher("h4/0/command")
    deadline = time.time() + 10
    while not feedback and time.time() < deadline:
        time.sleep(0.01)
    if not feedback:
        sys.exit("no feedback from the slave")
    home = feedback[-1]["pose"]
    session = random.getrandbits(64) | 1  # any non-zero id, the same all run
    seq = 0

    def stream(seconds, pose_at):
        nonlocal seq
        n, t = int(seconds * 1000), time.perf_counter()
        for k in range(n):
            seq += 1
            pub.put(command(session, seq, pose_at(k / n)))
            t += 0.001
            while time.perf_counter() < t:  # 1 kHz: the slave's watchdog wants ≤ 20 ms gaps
                pass

    def last():
        with lock:
            return feedback[-1]

    stream(1.0, lambda a: home)
    goal = (home[0] + 10.0, home[1], home[2], home[3])
    stream(2.0, lambda a: (home[0] + 10.0 * a, home[1], home[2], home[3]))
    stream(0.5, lambda a: goal)
    print("moved to", [round(v, 3) for v in last()["pose"]], "state", last()["state"])
    bad = {
        "wrong_version": lambda s: command(session, s, goal, version=3),
        "wrong_arm": lambda s: command(session, s, goal, arm=7),
        "stale": lambda s: command(session, 1, goal),
        "out_of_range (pose)": lambda s: command(session, s, (1e6, 0.0, 0.0, 0.0)),
        "out_of_range (force)": lambda s: command(session, s, goal, force_n=1e6),
        "implausible_energy": lambda s: command(session, s, goal, energy_in_j=1e6),
        "reserved_bits": lambda s: command(session, s, goal, reserved=1),
        "length_mismatch": lambda s: command(session, s, goal, body_len=100),
        "wild_seq": lambda s: command(session, 2**64 - 1, goal),
        "undecodable": lambda s: command(session, s, goal)[:50],
    }
    for name, make in bad.items():
        before = last()["rejected_count"]
        pub.put(make(seq + 1))
        time.sleep(0.002)
        seq += 1
        pub.put(command(session, seq, goal))  # a good one: the watchdog stays fed
        time.sleep(0.015)
        print(f"{name:22s} rejected_count {before} -> {last()['rejected_count']}")
    stream(0.3, lambda a: goal)
    print("end at", [round(v, 3) for v in last()["pose"]], "state", last()["state"])
    z.close()


if __name__ == "__main__":
    main()
