#!/usr/bin/env python3
"""An outside ROS 2 arm for tests/ros2_arm.rs: Python eclipse-zenoh and rosbags only.

It listens as a Zenoh peer on --listen (h4-slave run --arm crtk connects with --ros2-connect)
and acts as a CRTK arm under --ns: it publishes measured_cp (geometry_msgs/PoseStamped) and
measured_cf (WrenchStamped) at --rate-hz (rosbags' CDR, rmw_zenoh's key and 33-byte attachment
with its own GID and sequence numbers) and subscribes to servo_cp (PoseStamped), decoding every
sample with rosbags. Its platform follows the newest servo_cp as a first-order servo (time
constant --tau-s) from --start-mm; a spring wall (--wall-n-per-mm) below z = --wall-z-mm pushes
back along +z, and that force plus --noise-n of Gaussian noise on each force axis is measured_cf
(a real sensor's reading is never bit for bit the same twice; the slave's frozen-sensor rule
trips on one that is). Where permitted it runs under SCHED_FIFO --fifo-priority (below the
slave's 10), so that a loaded host does not starve the arm the slave's loop waits for.

From the first servo_cp on (time t):
  at --bad-at-s  --bad-each samples of each kind of bad input, interleaved with the good
                 stream: truncated CDR (the good payload less 8 bytes), a wrong type (a
                 TwistStamped on measured_cp under TwistStamped's type name and hash), a NaN
                 pose, a NaN wrench, a second publisher (a pose 40 mm above, under another GID);
  from --silent-at-s  nothing more is published (the arm falls silent); servo_cp is still
                 received for --tail-s, then it prints one JSON object on stdout and exits.
It prints "ready" on stderr when listening.
"""

import argparse
import json
import math
import os
import random
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
    def __init__(self, store):
        self.store = store
        self.lock = threading.Lock()
        self.samples = 0
        self.decoded = 0
        self.errors = []
        self.gids = set()
        self.seqs = []
        self.target_m = None
        # (monotonic time, x, y, z, quaternion norm, frame_id, stamp_ns, received unix ns)
        self.trace = []
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
                m = self.store.deserialize_cdr(bytes(sample.payload.to_bytes()), POSE)
                p, q = m.pose.position, m.pose.orientation
                theta = 2.0 * math.atan2(q.y, q.w)
                self.target_m = (p.x, p.y, p.z, theta)
                stamp = m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec
                self.trace.append((now, p.x, p.y, p.z,
                                   math.sqrt(q.x**2 + q.y**2 + q.z**2 + q.w**2),
                                   m.header.frame_id, stamp, time.time_ns()))
                self.decoded += 1
            except Exception as e:  # noqa: BLE001 - reported to the test
                self.errors.append(repr(e))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument('--listen', required=True)
    ap.add_argument('--domain', type=int, default=0)
    ap.add_argument('--ns', default='/arm')
    ap.add_argument('--rate-hz', type=float, default=500.0)
    ap.add_argument('--start-mm', required=True, help='x,y,z of the platform at rest, mm')
    ap.add_argument('--wall-z-mm', type=float, required=True)
    ap.add_argument('--wall-n-per-mm', type=float, default=20.0)
    ap.add_argument('--tau-s', type=float, default=0.003)
    ap.add_argument('--bad-at-s', type=float, default=2.0)
    ap.add_argument('--bad-each', type=int, default=5)
    ap.add_argument('--silent-at-s', type=float, default=4.0)
    ap.add_argument('--tail-s', type=float, default=1.0)
    ap.add_argument('--timeout-s', type=float, default=60.0)
    ap.add_argument('--noise-n', type=float, default=0.02)
    ap.add_argument('--seed', type=int, default=35)
    ap.add_argument('--fifo-priority', type=int, default=5)
    a = ap.parse_args()
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(a.fifo_priority))
    except (AttributeError, OSError):
        pass  # not permitted: normal scheduling
    rng = random.Random(a.seed)

    store = get_typestore(Stores.ROS2_JAZZY)
    h = {t: store.hash_rihs01(t) for t in (POSE, TWIST, WRENCH)}
    ns = a.ns.strip('/')
    key = lambda leaf, t: f'{a.domain}/{ns}/{leaf}/{dds_name(t)}/{h[t]}'  # noqa: E731

    conf = zenoh.Config()
    conf.insert_json5('mode', '"peer"')
    conf.insert_json5('listen/endpoints', json.dumps([a.listen]))
    conf.insert_json5('scouting/multicast/enabled', 'false')
    session = zenoh.open(conf)

    T = store.types
    Header, Time = T['std_msgs/msg/Header'], T['builtin_interfaces/msg/Time']
    Pose, Point, Quat = T['geometry_msgs/msg/Pose'], T['geometry_msgs/msg/Point'], \
        T['geometry_msgs/msg/Quaternion']
    PoseStamped, TwistStamped, WrenchStamped = T[POSE], T[TWIST], T[WRENCH]
    Twist, Wrench, Vector3 = T['geometry_msgs/msg/Twist'], T['geometry_msgs/msg/Wrench'], \
        T['geometry_msgs/msg/Vector3']

    def header(stamp_ns):
        return Header(stamp=Time(sec=stamp_ns // 1_000_000_000, nanosec=stamp_ns % 1_000_000_000),
                      frame_id='arm_base')

    def pose_bytes(p_m, stamp_ns):
        x, y, z, th = p_m
        msg = PoseStamped(header=header(stamp_ns),
                          pose=Pose(position=Point(x=x, y=y, z=z),
                                    orientation=Quat(x=0.0, y=math.sin(th / 2), z=0.0,
                                                     w=math.cos(th / 2))))
        return bytes(store.serialize_cdr(msg, POSE))

    def wrench_bytes(fz_n, stamp_ns):
        zero = Vector3(x=0.0, y=0.0, z=0.0)
        n = [rng.gauss(0.0, a.noise_n) for _ in range(3)]
        force = Vector3(x=n[0], y=n[1], z=fz_n + n[2])
        msg = WrenchStamped(header=header(stamp_ns), wrench=Wrench(force=force, torque=zero))
        return bytes(store.serialize_cdr(msg, WRENCH))

    def twist_bytes(stamp_ns):
        v = Vector3(x=0.0, y=0.0, z=0.0)
        return bytes(store.serialize_cdr(
            TwistStamped(header=header(stamp_ns), twist=Twist(linear=v, angular=v)), TWIST))

    cmds = Commands(store)
    sub = session.declare_subscriber(key('servo_cp', POSE), cmds.on_sample)
    gid = os.urandom(16)
    pose_pub = Publisher(session, key('measured_cp', POSE), gid)
    wrench_pub = Publisher(session, key('measured_cf', WRENCH), os.urandom(16))
    second = Publisher(session, key('measured_cp', POSE), os.urandom(16))
    wrong = Publisher(session, key('measured_cp', TWIST), gid)
    print('ready', file=sys.stderr, flush=True)

    sx, sy, sz = (float(v) * 1e-3 for v in a.start_mm.split(','))
    pose = [sx, sy, sz, 0.0]
    wall_z_m = a.wall_z_mm * 1e-3
    period = 1.0 / a.rate_hz
    sent = {'good_poses': 0, 'good_wrenches': 0, 'truncated': 0, 'wrong_type': 0,
            'non_finite': 0, 'second_publisher': 0}
    max_force_n = 0.0
    deadline = time.monotonic() + a.timeout_s
    last = time.monotonic()
    next_t = last
    bad_done = False
    while True:
        now = time.monotonic()
        if now > deadline:
            print(json.dumps({'error': 'timeout', 'commands': cmds.samples}))
            return
        with cmds.lock:
            target, first_at = cmds.target_m, cmds.first_at
        t = None if first_at is None else now - first_at
        if t is not None and t >= a.silent_at_s:
            break
        dt = now - last
        last = now
        if target is not None:
            k = min(1.0, dt / a.tau_s)
            pose = [p + (q - p) * k for p, q in zip(pose, target)]
        fz_n = max(0.0, (wall_z_m - pose[2]) * 1e3 * a.wall_n_per_mm)
        max_force_n = max(max_force_n, fz_n)
        stamp = time.time_ns()
        good = pose_bytes(pose, stamp)
        pose_pub.put(good, stamp)
        sent['good_poses'] += 1
        wrench_pub.put(wrench_bytes(fz_n, stamp), stamp)
        sent['good_wrenches'] += 1
        if t is not None and t >= a.bad_at_s and not bad_done:
            bad_done = True
            for _ in range(a.bad_each):
                pose_pub.put(good[:-8], stamp)
                sent['truncated'] += 1
                wrong.put(twist_bytes(stamp), stamp)
                sent['wrong_type'] += 1
                pose_pub.put(pose_bytes([float('nan'), pose[1], pose[2], 0.0], stamp), stamp)
                wrench_pub.put(wrench_bytes(float('nan'), stamp), stamp)
                sent['non_finite'] += 2
                second.put(pose_bytes([pose[0], pose[1], pose[2] + 0.04, 0.0], stamp), stamp)
                sent['second_publisher'] += 1
        next_t += period
        time.sleep(max(0.0, next_t - time.monotonic()))
    silent_at = time.monotonic()
    time.sleep(a.tail_s)
    with cmds.lock:
        trace = list(cmds.trace)
        zs = [x[3] for x in trace]
        steps = [abs(b[i] - a_[i]) for a_, b in zip(trace, trace[1:]) for i in (1, 2, 3)]
        out = {
            'sent': sent,
            'commands': cmds.samples,
            'decoded': cmds.decoded,
            'decode_errors': cmds.errors[:5],
            'gids': sorted(cmds.gids),
            'seq_increasing_by_one': all(b == a_ + 1 for a_, b in zip(cmds.seqs, cmds.seqs[1:])),
            'frame_ids': sorted({x[5] for x in trace}),
            'first_command_m': list(trace[0][1:4]) if trace else None,
            'command_z_min_m': min(zs, default=None),
            'command_z_max_m': max(zs, default=None),
            'max_command_step_m': max(steps, default=0.0),
            'quaternion_norm_error_max': max((abs(x[4] - 1.0) for x in trace), default=None),
            'stamps_increasing': all(b[6] >= a_[6] for a_, b in zip(trace, trace[1:])),
            'stamp_age_max_s': max((abs(x[7] - x[6]) * 1e-9 for x in trace), default=None),
            'max_force_n': max_force_n,
            'commands_after_silence': sum(1 for x in trace if x[0] >= silent_at + 0.1),
        }
    print(json.dumps(out))
    del sub
    session.close()


if __name__ == '__main__':
    main()
