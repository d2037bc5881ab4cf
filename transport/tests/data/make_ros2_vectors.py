#!/usr/bin/env python3
"""Regenerates ros2_vectors.json: the outside implementation that transport/tests/ros2_vectors.rs
checks h4_transport::ros2 against.

For every message type h4_transport::ros2 knows, rosbags (https://gitlab.com/ternaris/rosbags,
a pure-Python ROS bag library with its own CDR serialiser and RIHS01 hasher) gives
  * the RIHS01 type hash (REP 2011) and the exact JSON string it hashed,
  * the CDR_LE bytes (with the 4-byte encapsulation header) of one fixed instance; the Rust test
    builds the same instance, encodes it and compares bytes, and decodes rosbags' bytes back.

The instances below must match `instances()` in ros2_vectors.rs field for field.

Usage (no ROS installation needed):
    python3 -m venv /tmp/rosbags-venv && /tmp/rosbags-venv/bin/pip install rosbags
    /tmp/rosbags-venv/bin/python transport/tests/data/make_ros2_vectors.py
"""

import json
from importlib.metadata import version
from pathlib import Path

import numpy as np
import rosbags.typesys.store as rosbags_store
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

# crtk_msgs/msg/OperatingState, verbatim from collaborative-robotics/crtk_msgs (msg/OperatingState.msg).
CRTK_OPERATING_STATE_MSG = """\
std_msgs/Header header
string          state
bool            is_homed
bool            is_busy
"""

# Every type h4_transport::ros2::type_hash describes.
TYPE_NAMES = [
    'builtin_interfaces/msg/Time',
    'std_msgs/msg/Header',
    'std_msgs/msg/String',
    'std_msgs/msg/MultiArrayDimension',
    'std_msgs/msg/MultiArrayLayout',
    'std_msgs/msg/Float64MultiArray',
    'geometry_msgs/msg/Point',
    'geometry_msgs/msg/Quaternion',
    'geometry_msgs/msg/Pose',
    'geometry_msgs/msg/PoseStamped',
    'geometry_msgs/msg/Vector3',
    'geometry_msgs/msg/Twist',
    'geometry_msgs/msg/TwistStamped',
    'geometry_msgs/msg/Wrench',
    'geometry_msgs/msg/WrenchStamped',
    'sensor_msgs/msg/Joy',
    'crtk_msgs/msg/OperatingState',
]


def typestore():
    store = get_typestore(Stores.ROS2_JAZZY)
    store.register(get_types_from_msg(CRTK_OPERATING_STATE_MSG, 'crtk_msgs/msg/OperatingState'))
    return store


def hash_with_json(store, type_name):
    """rosbags' RIHS01 hash of type_name and the JSON text it hashed (captured, not rebuilt)."""
    captured = []
    real_dumps = rosbags_store.json.dumps

    def capturing_dumps(obj, *args, **kwargs):
        text = real_dumps(obj, *args, **kwargs)
        captured.append(text)
        return text

    rosbags_store.json.dumps = capturing_dumps
    try:
        rihs01 = store.hash_rihs01(type_name)
    finally:
        rosbags_store.json.dumps = real_dumps
    assert len(captured) == 1, captured
    return rihs01, captured[0]


def instances(store):
    """One fixed instance per type; mirrors `instances()` in ros2_vectors.rs."""
    t = store.types
    Time = t['builtin_interfaces/msg/Time']
    Header = t['std_msgs/msg/Header']
    Point = t['geometry_msgs/msg/Point']
    Quaternion = t['geometry_msgs/msg/Quaternion']
    Pose = t['geometry_msgs/msg/Pose']
    Vector3 = t['geometry_msgs/msg/Vector3']
    Twist = t['geometry_msgs/msg/Twist']
    Wrench = t['geometry_msgs/msg/Wrench']
    Dim = t['std_msgs/msg/MultiArrayDimension']
    Layout = t['std_msgs/msg/MultiArrayLayout']

    stamp = Time(sec=1_700_000_000, nanosec=123_456_789)

    def header(frame_id):
        return Header(stamp=stamp, frame_id=frame_id)

    pose = Pose(
        position=Point(x=0.1, y=-0.2, z=0.3),
        orientation=Quaternion(x=0.0, y=0.6, z=0.0, w=0.8),
    )
    twist = Twist(
        linear=Vector3(x=0.01, y=0.02, z=-0.03),
        angular=Vector3(x=0.0, y=0.5, z=0.0),
    )
    wrench = Wrench(
        force=Vector3(x=1.5, y=-2.5, z=9.81),
        torque=Vector3(x=0.0, y=-0.125, z=0.0),
    )
    layout = Layout(
        dim=[Dim(label='rows', size=2, stride=6), Dim(label='cols', size=3, stride=3)],
        data_offset=0,
    )
    return {
        'builtin_interfaces/msg/Time': stamp,
        'std_msgs/msg/Header': header('h4_base'),
        'std_msgs/msg/String': t['std_msgs/msg/String'](data='hello'),
        'std_msgs/msg/MultiArrayDimension': Dim(label='rows', size=2, stride=6),
        'std_msgs/msg/MultiArrayLayout': layout,
        'std_msgs/msg/Float64MultiArray': t['std_msgs/msg/Float64MultiArray'](
            layout=layout, data=np.array([1.0, 2.0, 3.0, 4.0, 5.0, 6.5], dtype=np.float64)
        ),
        'geometry_msgs/msg/Point': Point(x=0.125, y=-0.25, z=0.5),
        'geometry_msgs/msg/Quaternion': Quaternion(x=0.0, y=0.6, z=0.0, w=0.8),
        'geometry_msgs/msg/Pose': pose,
        'geometry_msgs/msg/PoseStamped': t['geometry_msgs/msg/PoseStamped'](
            header=header('world'), pose=pose
        ),
        'geometry_msgs/msg/Vector3': Vector3(x=1.0, y=-2.0, z=3.5),
        'geometry_msgs/msg/Twist': twist,
        'geometry_msgs/msg/TwistStamped': t['geometry_msgs/msg/TwistStamped'](
            header=header('h4_tool'), twist=twist
        ),
        'geometry_msgs/msg/Wrench': wrench,
        'geometry_msgs/msg/WrenchStamped': t['geometry_msgs/msg/WrenchStamped'](
            header=header('tool0'), wrench=wrench
        ),
        'sensor_msgs/msg/Joy': t['sensor_msgs/msg/Joy'](
            header=header('joy'),
            axes=np.array([0.5, -1.0, 0.25], dtype=np.float32),
            buttons=np.array([1, 0, 1, 1], dtype=np.int32),
        ),
        'crtk_msgs/msg/OperatingState': t['crtk_msgs/msg/OperatingState'](
            header=header('h4'), state='ENABLED', is_homed=True, is_busy=False
        ),
    }


def main():
    store = typestore()
    msgs = instances(store)
    assert sorted(msgs) == sorted(TYPE_NAMES)
    out = []
    for type_name in TYPE_NAMES:
        rihs01, hashed_json = hash_with_json(store, type_name)
        cdr = bytes(store.serialize_cdr(msgs[type_name], type_name, little_endian=True))
        # rosbags reads its own bytes back (a check of this script, not of the Rust code).
        back = store.deserialize_cdr(cdr, type_name)
        assert bytes(store.serialize_cdr(back, type_name, little_endian=True)) == cdr
        out.append({
            'type_name': type_name,
            'rihs01': rihs01,
            'hashed_json': hashed_json,
            'cdr_hex': cdr.hex(),
        })
    doc = {
        'generator': 'transport/tests/data/make_ros2_vectors.py',
        'rosbags_version': version('rosbags'),
        'typestore': 'ros2_jazzy (+ crtk_msgs/msg/OperatingState from its .msg)',
        'messages': out,
    }
    path = Path(__file__).with_name('ros2_vectors.json')
    path.write_text(json.dumps(doc, indent=2) + '\n', encoding='utf-8')
    print(f'wrote {path} ({len(out)} types, rosbags {doc["rosbags_version"]})')


if __name__ == '__main__':
    main()
