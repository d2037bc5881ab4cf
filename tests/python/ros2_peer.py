#!/usr/bin/env python3
"""An outside ROS 2 peer for tests/ros2_peer.rs: Python eclipse-zenoh and rosbags only, no ROS.

It listens as a Zenoh peer on --listen (the h4 processes connect to it with --ros2-connect),
subscribes to the CRTK topics of the slave (--slave-ns) and of the master (--master-ns) by the
exact rmw_zenoh key expressions it builds itself: <domain>/<topic>/<dds type>/<RIHS01 hash>, the
hash computed by rosbags from the type description. For every sample it checks the 33-byte
attachment (sequence number i64 LE, source timestamp i64 LE, GID length 16, GID) and decodes the
payload with rosbags' CDR deserialiser. As a negative control it also subscribes to the slave's
measured_cp under a wrong type hash (the hash of TwistStamped), which must receive nothing.
While the publishers are alive it lists the liveliness tokens under @ros2_lv/<domain>/**.

It prints "ready" on stderr when listening, then one JSON object on stdout when done:
  {"topics": {key: {...}}, "wrong_hash_samples": n, "tokens": [...], "rihs01": {type: hash}}
"""

import argparse
import json
import math
import struct
import sys
import threading
import time

import zenoh
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

CRTK_OPERATING_STATE_MSG = """\
std_msgs/Header header
string          state
bool            is_homed
bool            is_busy
"""

SLAVE = [
    ('measured_cp', 'geometry_msgs/msg/PoseStamped'),
    ('measured_cv', 'geometry_msgs/msg/TwistStamped'),
    ('measured_cf', 'geometry_msgs/msg/WrenchStamped'),
    ('setpoint_cf', 'geometry_msgs/msg/WrenchStamped'),
    ('operating_state', 'crtk_msgs/msg/OperatingState'),
]
MASTER = [
    ('measured_cp', 'geometry_msgs/msg/PoseStamped'),
    ('servo_cf', 'geometry_msgs/msg/WrenchStamped'),
]


def dds_name(type_name):
    pkg, kind, name = type_name.split('/')
    return f'{pkg}::{kind}::dds_::{name}_'


def summary_of(type_name, msg):
    """The decoded message's fields the Rust test asserts on."""
    out = {'frame_id': msg.header.frame_id,
           'stamp_ns': msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec}
    if type_name.endswith('PoseStamped'):
        p, q = msg.pose.position, msg.pose.orientation
        out.update(position_m=[p.x, p.y, p.z], orientation=[q.x, q.y, q.z, q.w],
                   quaternion_norm=math.sqrt(q.x**2 + q.y**2 + q.z**2 + q.w**2))
    elif type_name.endswith('TwistStamped'):
        out.update(linear=[msg.twist.linear.x, msg.twist.linear.y, msg.twist.linear.z])
    elif type_name.endswith('WrenchStamped'):
        f, t = msg.wrench.force, msg.wrench.torque
        out.update(force_n=[f.x, f.y, f.z], torque_n_m=[t.x, t.y, t.z])
    else:
        out.update(state=msg.state, is_homed=bool(msg.is_homed), is_busy=bool(msg.is_busy))
    return out


class Topic:
    def __init__(self, store, type_name):
        self.store, self.type_name = store, type_name
        self.lock = threading.Lock()
        self.samples = 0
        self.decoded = 0
        self.decode_errors = []
        self.attachment_errors = []
        self.seqs = []
        self.gids = set()
        self.stamps_ns = []
        self.first = None
        self.last = None
        self.non_finite = 0

    def on_sample(self, sample):
        with self.lock:
            self.samples += 1
            att = sample.attachment
            raw = bytes(att.to_bytes()) if att is not None else b''
            if len(raw) != 33 or raw[16] != 16:
                self.attachment_errors.append(len(raw))
            else:
                seq, stamp = struct.unpack_from('<qq', raw, 0)
                self.seqs.append(seq)
                self.stamps_ns.append(stamp)
                self.gids.add(raw[17:33].hex())
            try:
                msg = self.store.deserialize_cdr(bytes(sample.payload.to_bytes()), self.type_name)
                s = summary_of(self.type_name, msg)
                nums = [v for k in s.values() if isinstance(k, list) for v in k]
                if not all(math.isfinite(v) for v in nums):
                    self.non_finite += 1
                self.decoded += 1
                if self.first is None:
                    self.first = s
                self.last = s
            except Exception as e:  # noqa: BLE001 - every failure is reported to the test
                self.decode_errors.append(repr(e))

    def report(self):
        with self.lock:
            seqs = self.seqs
            return {
                'type': self.type_name,
                'samples': self.samples,
                'decoded': self.decoded,
                'decode_errors': self.decode_errors[:5],
                'attachment_errors': len(self.attachment_errors),
                'seq_first': seqs[0] if seqs else None,
                'seq_last': seqs[-1] if seqs else None,
                'seq_increasing_by_one': all(b == a + 1 for a, b in zip(seqs, seqs[1:])),
                'gids': sorted(self.gids),
                'attachment_stamp_matches_header': self.last is not None and bool(self.stamps_ns)
                and self.stamps_ns[-1] == self.last['stamp_ns'],
                'non_finite': self.non_finite,
                'first': self.first,
                'last': self.last,
            }


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument('--listen', required=True)
    ap.add_argument('--domain', type=int, default=0)
    ap.add_argument('--slave-ns', default='/h4')
    ap.add_argument('--master-ns', default='/h4_master')
    ap.add_argument('--min-samples', type=int, default=50)
    ap.add_argument('--timeout-s', type=float, default=60.0)
    a = ap.parse_args()

    store = get_typestore(Stores.ROS2_JAZZY)
    store.register(get_types_from_msg(CRTK_OPERATING_STATE_MSG, 'crtk_msgs/msg/OperatingState'))
    hashes = {t: store.hash_rihs01(t) for _, t in SLAVE + MASTER}

    conf = zenoh.Config()
    conf.insert_json5('mode', '"peer"')
    conf.insert_json5('listen/endpoints', json.dumps([a.listen]))
    conf.insert_json5('scouting/multicast/enabled', 'false')
    session = zenoh.open(conf)

    topics, subs = {}, []
    for ns, entries in ((a.slave_ns, SLAVE), (a.master_ns, MASTER)):
        for leaf, type_name in entries:
            key = f'{a.domain}/{ns.strip("/")}/{leaf}/{dds_name(type_name)}/{hashes[type_name]}'
            t = Topic(store, type_name)
            topics[key] = t
            subs.append(session.declare_subscriber(key, t.on_sample))

    wrong = {'n': 0}
    wrong_key = (f'{a.domain}/{a.slave_ns.strip("/")}/measured_cp/'
                 f'{dds_name("geometry_msgs/msg/PoseStamped")}/'
                 f'{hashes["geometry_msgs/msg/TwistStamped"]}')

    def on_wrong(_sample):
        wrong['n'] += 1

    subs.append(session.declare_subscriber(wrong_key, on_wrong))
    print('ready', file=sys.stderr, flush=True)

    deadline = time.monotonic() + a.timeout_s
    while time.monotonic() < deadline:
        if all(t.samples >= a.min_samples for t in topics.values()):
            break
        time.sleep(0.05)

    tokens = []
    for reply in session.liveliness().get(f'@ros2_lv/{a.domain}/**', timeout=5.0):
        try:
            tokens.append(str(reply.ok.key_expr))
        except Exception:  # noqa: BLE001 - an error reply is not a token
            pass
    # Publishers still alive: a little longer, so a late wrong-key sample would be seen.
    time.sleep(0.3)
    print(json.dumps({
        'topics': {k: t.report() for k, t in topics.items()},
        'wrong_hash_key': wrong_key,
        'wrong_hash_samples': wrong['n'],
        'tokens': sorted(tokens),
        'rihs01': hashes,
    }))
    session.close()


if __name__ == '__main__':
    main()
