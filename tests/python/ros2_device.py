#!/usr/bin/env python3
"""An outside ROS 2 haptic device for tests/ros2_device.rs: Python eclipse-zenoh and rosbags only.

It listens as a Zenoh peer on --listen (h4-master run --device crtk connects with
--ros2-connect) and acts as a CRTK device under --ns: it publishes measured_cp
(geometry_msgs/PoseStamped, rosbags' CDR, rmw_zenoh's key and 33-byte attachment with its own
GID and sequence numbers) at --rate-hz and subscribes to servo_cf (WrenchStamped), decoding every
sample with rosbags.

Until the first servo_cf arrives it publishes the rest pose (0, 0, 0). From then on (time t):
  0.0-0.5 s  rest;  0.5-1.5 s  down to z = --press-mm;  1.5-3.0 s  hold there;
  at 2.0 s   --bad-each samples of each kind of bad input, interleaved with the good stream:
             truncated CDR (the good payload less 8 bytes), a wrong type (a TwistStamped on
             measured_cp under TwistStamped's type name and hash), a NaN pose, a second
             publisher (a good pose under another GID);
  2.4-2.5 s  --outside-mm below the press (outside the box the test maps, so clamped);
  from --silent-at-s  no more poses (the device falls silent); servo_cf is still received
             for --tail-s, then it prints one JSON object on stdout and exits.
It prints "ready" on stderr when listening.
"""

import argparse
import json
import math
import os
import struct
import sys
import threading
import time

import zenoh
from rosbags.typesys import Stores, get_typestore

POSE = 'geometry_msgs/msg/PoseStamped'
TWIST = 'geometry_msgs/msg/TwistStamped'
WRENCH = 'geometry_msgs/msg/WrenchStamped'


def dds_name(type_name):
    pkg, kind, name = type_name.split('/')
    return f'{pkg}::{kind}::dds_::{name}_'


class Publisher:
    """One rmw_zenoh publisher: a key, a GID, sequence numbers from 1."""

    def __init__(self, session, key, gid):
        self.pub = session.declare_publisher(key)
        self.gid = gid
        self.seq = 0

    def put(self, payload, stamp_ns):
        self.seq += 1
        att = struct.pack('<qqB', self.seq, stamp_ns, 16) + self.gid
        self.pub.put(payload, attachment=att)


class Commands:
    def __init__(self, store, t0):
        self.store = store
        self.lock = threading.Lock()
        self.t0 = t0
        self.samples = 0
        self.decoded = 0
        self.errors = []
        self.gids = set()
        self.seqs = []
        self.trace = []  # (t since the first command, |F|)
        self.first_at = None

    def on_sample(self, sample):
        now = time.monotonic()
        with self.lock:
            self.samples += 1
            if self.first_at is None:
                self.first_at = now
            raw = bytes(sample.attachment.to_bytes()) if sample.attachment is not None else b''
            if len(raw) == 33 and raw[16] == 16:
                self.seqs.append(struct.unpack_from('<q', raw, 0)[0])
                self.gids.add(raw[17:33].hex())
            try:
                m = self.store.deserialize_cdr(bytes(sample.payload.to_bytes()), WRENCH)
                f = m.wrench.force
                self.trace.append((now - self.first_at, math.sqrt(f.x**2 + f.y**2 + f.z**2),
                                   m.header.frame_id))
                self.decoded += 1
            except Exception as e:  # noqa: BLE001 - reported to the test
                self.errors.append(repr(e))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument('--listen', required=True)
    ap.add_argument('--domain', type=int, default=0)
    ap.add_argument('--ns', default='/h4_device')
    ap.add_argument('--rate-hz', type=float, default=500.0)
    ap.add_argument('--press-mm', type=float, default=-5.0)
    ap.add_argument('--outside-mm', type=float, default=-2.0)
    ap.add_argument('--bad-each', type=int, default=5)
    ap.add_argument('--silent-at-s', type=float, default=3.0)
    ap.add_argument('--tail-s', type=float, default=1.0)
    ap.add_argument('--timeout-s', type=float, default=60.0)
    a = ap.parse_args()

    store = get_typestore(Stores.ROS2_JAZZY)
    h = {t: store.hash_rihs01(t) for t in (POSE, TWIST, WRENCH)}
    ns = a.ns.strip('/')
    key = lambda leaf, t: f'{a.domain}/{ns}/{leaf}/{dds_name(t)}/{h[t]}'  # noqa: E731

    conf = zenoh.Config()
    conf.insert_json5('mode', '"peer"')
    conf.insert_json5('listen/endpoints', json.dumps([a.listen]))
    conf.insert_json5('scouting/multicast/enabled', 'false')
    session = zenoh.open(conf)

    Header = store.types['std_msgs/msg/Header']
    Time = store.types['builtin_interfaces/msg/Time']
    Pose = store.types['geometry_msgs/msg/Pose']
    Point = store.types['geometry_msgs/msg/Point']
    Quat = store.types['geometry_msgs/msg/Quaternion']
    PoseStamped = store.types[POSE]
    TwistStamped = store.types[TWIST]
    Twist = store.types['geometry_msgs/msg/Twist']
    Vector3 = store.types['geometry_msgs/msg/Vector3']

    def header(stamp_ns):
        return Header(stamp=Time(sec=stamp_ns // 1_000_000_000, nanosec=stamp_ns % 1_000_000_000),
                      frame_id='device_base')

    def pose_bytes(z_m, stamp_ns, x_m=0.0):
        msg = PoseStamped(header=header(stamp_ns),
                          pose=Pose(position=Point(x=x_m, y=0.0, z=z_m),
                                    orientation=Quat(x=0.0, y=0.0, z=0.0, w=1.0)))
        return bytes(store.serialize_cdr(msg, POSE))

    def twist_bytes(stamp_ns):
        v = Vector3(x=0.0, y=0.0, z=0.0)
        return bytes(store.serialize_cdr(
            TwistStamped(header=header(stamp_ns), twist=Twist(linear=v, angular=v)), TWIST))

    cmds = Commands(store, time.monotonic())
    sub = session.declare_subscriber(key('servo_cf', WRENCH), cmds.on_sample)
    gid = os.urandom(16)
    pose_pub = Publisher(session, key('measured_cp', POSE), gid)
    second = Publisher(session, key('measured_cp', POSE), os.urandom(16))
    wrong = Publisher(session, key('measured_cp', TWIST), gid)
    print('ready', file=sys.stderr, flush=True)

    period = 1.0 / a.rate_hz
    sent = {'good': 0, 'truncated': 0, 'wrong_type': 0, 'non_finite': 0,
            'second_publisher': 0, 'outside': 0, 'before_start': 0}
    deadline = time.monotonic() + a.timeout_s
    # Rest until the master answers.
    while cmds.first_at is None:
        if time.monotonic() > deadline:
            print(json.dumps({'error': 'no servo_cf'}))
            return
        pose_pub.put(pose_bytes(0.0, time.time_ns()), time.time_ns())
        sent['before_start'] += 1
        time.sleep(period)
    start = time.monotonic()
    next_t = start
    bad_done = False
    while True:
        t = time.monotonic() - start
        if t >= a.silent_at_s:
            break
        if t < 0.5:
            z_mm = 0.0
        elif t < 1.5:
            z_mm = a.press_mm * (t - 0.5)
        else:
            z_mm = a.press_mm
        outside = 2.4 <= t < 2.5
        if outside:
            z_mm = a.press_mm + a.outside_mm
            sent['outside'] += 1
        stamp = time.time_ns()
        pose_pub.put(pose_bytes(z_mm * 1e-3, stamp), stamp)
        sent['good'] += 1
        if t >= 2.0 and not bad_done:
            bad_done = True
            good = pose_bytes(z_mm * 1e-3, stamp)
            for _ in range(a.bad_each):
                pose_pub.put(good[:-8], stamp)
                sent['truncated'] += 1
                wrong.put(twist_bytes(stamp), stamp)
                sent['wrong_type'] += 1
                pose_pub.put(pose_bytes(float('nan'), stamp), stamp)
                sent['non_finite'] += 1
                second.put(good, stamp)
                sent['second_publisher'] += 1
        next_t += period
        time.sleep(max(0.0, next_t - time.monotonic()))
    silent_at = time.monotonic() - cmds.first_at
    time.sleep(a.tail_s)
    with cmds.lock:
        trace = list(cmds.trace)
        out = {
            'sent': sent,
            'silent_at_s': silent_at,
            'commands': cmds.samples,
            'decoded': cmds.decoded,
            'decode_errors': cmds.errors[:5],
            'gids': sorted(cmds.gids),
            'seq_increasing_by_one': all(b == a_ + 1 for a_, b in zip(cmds.seqs, cmds.seqs[1:])),
            'frame_ids': sorted({f for _, _, f in trace}),
            'max_force_n_while_held': max((f for t, f, _ in trace if 1.5 <= t < silent_at),
                                          default=0.0),
            'max_force_n_last_200ms': max((f for t, f, _ in trace if t >= silent_at + a.tail_s - 0.2),
                                          default=None),
            'commands_last_200ms': sum(1 for t, _, _ in trace if t >= silent_at + a.tail_s - 0.2),
        }
    print(json.dumps(out))
    del sub
    session.close()


if __name__ == '__main__':
    main()
