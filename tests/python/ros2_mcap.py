"""Opens an h4-teleop recording made with `--record-ros2` as ROS 2 tools would, without ROS
(tests/ros2_mcap.rs):

* PyPI `mcap` reads the file; `mcap_ros2.decoder` (mcap-ros2-support, Foxglove's decoder)
  decodes every ROS 2 message from its channel's `ros2msg` schema text alone;
* `rosbags` parses each definition of the schema text on its own (`get_types_from_msg`),
  decodes every message with those types, and, for the types its built-in Jazzy store knows,
  compares the schema's fields with the official definitions and decodes the message with
  the official types too.

Prints one JSON object: per ROS 2 topic its schema, encodings, counts and the checks' results;
the Rust test asserts on it.
"""

import argparse
import json
import math
import re
import sys

from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

DELIMITER = "=" * 80


def split_definitions(schema_name, text):
    """[(type name, .msg text)]: the top-level type, then each `MSG:` section."""
    parts = text.split("\n" + DELIMITER + "\n")
    out = [(schema_name, parts[0])]
    for p in parts[1:]:
        first, _, body = p.partition("\n")
        m = re.fullmatch(r"MSG: (\S+)", first)
        if not m:
            raise ValueError(f"section without a MSG: line: {first!r}")
        out.append((m.group(1), body))
    return out


def fields_of(store, name):
    """[(field name, normalised type)] of `name` in a rosbags typestore."""
    return [(f[0], repr(f[1])) for f in store.fielddefs[name][1]]


def numbers(msg, prefix=""):
    """Every float field of a decoded message (nested), flattened."""
    out = []
    for slot in getattr(msg, "__slots__", None) or getattr(msg, "__dataclass_fields__", {}):
        v = getattr(msg, slot)
        if isinstance(v, float):
            out.append(v)
        elif hasattr(v, "__slots__") or hasattr(v, "__dataclass_fields__"):
            out.extend(numbers(v))
    return out


def stamp_ns(header):
    return header.stamp.sec * 1_000_000_000 + header.stamp.nanosec


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("mcap")
    args = ap.parse_args()

    jazzy = get_typestore(Stores.ROS2_JAZZY)
    topics = {}
    other_topics = {}
    with open(args.mcap, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        # rosbags: one store per schema, from the schema text only.
        stores = {}
        for ch in summary.channels.values():
            schema = summary.schemas[ch.schema_id]
            if schema.encoding != "ros2msg":
                other_topics[ch.topic] = schema.encoding
                continue
            text = schema.data.decode()
            store = get_typestore(Stores.EMPTY)
            types = {}
            for name, body in split_definitions(schema.name, text):
                types.update(get_types_from_msg(body, name))
            store.register(types)
            stores[ch.topic] = store
            official = {}
            for name in types:
                if name in jazzy.fielddefs:
                    official[name] = fields_of(store, name) == fields_of(jazzy, name)
            topics[ch.topic] = {
                "schema_name": schema.name,
                "schema_encoding": schema.encoding,
                "message_encoding": ch.message_encoding,
                "definitions": sorted(types),
                "matches_official": official,
                "messages": 0,
                "decoded_mcap_ros2": 0,
                "decoded_rosbags": 0,
                "decoded_official": 0,
                "agree": True,
                "non_finite": 0,
                "frame_ids": [],
                "stamps_increasing": True,
                "log_times_increasing": True,
                "stamp_equals_log_time": True,
                "first_log_time_ns": None,
                "last_log_time_ns": None,
                "errors": [],
            }
        for schema, channel, message, decoded in reader.iter_decoded_messages(
            topics=list(topics)
        ):
            t = topics[channel.topic]
            t["messages"] += 1
            t["decoded_mcap_ros2"] += 1
            try:
                ours = stores[channel.topic].deserialize_cdr(message.data, schema.name)
                t["decoded_rosbags"] += 1
            except Exception as e:  # noqa: BLE001 - reported, the test fails on it
                t["errors"].append(f"rosbags: {e}")
                continue
            if schema.name in jazzy.fielddefs:
                try:
                    off = jazzy.deserialize_cdr(message.data, schema.name)
                    t["decoded_official"] += 1
                    if numbers(off) != numbers(ours):
                        t["agree"] = False
                except Exception as e:  # noqa: BLE001
                    t["errors"].append(f"rosbags jazzy: {e}")
            if stamp_ns(decoded.header) != stamp_ns(ours.header):
                t["agree"] = False
            if decoded.header.frame_id != ours.header.frame_id:
                t["agree"] = False
            vals = numbers(ours)
            if not all(math.isfinite(v) for v in vals):
                t["non_finite"] += 1
            if ours.header.frame_id not in t["frame_ids"]:
                t["frame_ids"].append(ours.header.frame_id)
            s = stamp_ns(ours.header)
            if s != message.log_time:
                t["stamp_equals_log_time"] = False
            last = t["last_log_time_ns"]
            if last is not None:
                if message.log_time <= last:
                    t["log_times_increasing"] = False
                if s <= t["last_stamp_ns"]:
                    t["stamps_increasing"] = False
            if t["first_log_time_ns"] is None:
                t["first_log_time_ns"] = message.log_time
            t["last_log_time_ns"] = message.log_time
            t["last_stamp_ns"] = s
            if schema.name == "geometry_msgs/msg/PoseStamped":
                p, q = decoded.pose.position, decoded.pose.orientation
                t["last_position_m"] = [p.x, p.y, p.z]
                t["last_quaternion_norm"] = math.sqrt(q.x**2 + q.y**2 + q.z**2 + q.w**2)
            elif schema.name == "geometry_msgs/msg/WrenchStamped":
                t["last_force_n"] = [
                    decoded.wrench.force.x,
                    decoded.wrench.force.y,
                    decoded.wrench.force.z,
                ]
            elif schema.name == "crtk_msgs/msg/OperatingState":
                t["last_state"] = decoded.state
                t.setdefault("states", [])
                if decoded.state not in t["states"]:
                    t["states"].append(decoded.state)
                t["last_is_homed"] = decoded.is_homed
    for t in topics.values():
        t.pop("last_stamp_ns", None)
    json.dump({"topics": topics, "other_topics": other_topics}, sys.stdout, sort_keys=True)
    print()


if __name__ == "__main__":
    main()
