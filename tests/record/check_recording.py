#!/usr/bin/env python3
"""Reads a flyd recording with third-party readers and checks it against the run.

    check_recording.py RECORDING.mcap CANDUMP.log EXPECTED.json

Readers: Python `mcap` (the MCAP reader), `mcap-protobuf-support` (decodes the Foxglove
protobuf schemas from the descriptors stored in the file), `json` for flyd's JSON channels.
EXPECTED.json holds what the daemon reported at its end (frames per camera, pairs,
generations, snapshots, commands, flies_every, record_dropped, flies_skipped). Prints one JSON line of
figures; exits 1 with the reasons on any mismatch.
"""
import json
import sys
from collections import Counter, defaultdict

from mcap.decoder import DecoderFactory as BaseFactory
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory as ProtobufFactory


class JsonFactory(BaseFactory):
    def decoder_for(self, message_encoding, schema):
        if message_encoding == "json":
            return lambda data: json.loads(data)
        return None


SCHEMAS = {
    "/camera/left/image": ("foxglove.RawImage", "protobuf"),
    "/camera/right/image": ("foxglove.RawImage", "protobuf"),
    "/camera/left/image/compressed": ("foxglove.CompressedImage", "protobuf"),
    "/camera/right/image/compressed": ("foxglove.CompressedImage", "protobuf"),
    "/camera/left/calibration": ("foxglove.CameraCalibration", "protobuf"),
    "/camera/right/calibration": ("foxglove.CameraCalibration", "protobuf"),
    "/tf": ("foxglove.FrameTransforms", "protobuf"),
    "/flyd/flies": ("foxglove.PointCloud", "protobuf"),
    "/flyd/scene": ("foxglove.SceneUpdate", "protobuf"),
    "/flyd/pair": ("flyd.Pair", "jsonschema"),
    "/flyd/perception": ("flyd.Perception", "jsonschema"),
    "/flyd/decision": ("flyd.Decision", "jsonschema"),
    "/flyd/stats": ("flyd.Stats", "jsonschema"),
    "/can/tx": ("flyd.CanFrame", "jsonschema"),
    "/can/rx": ("flyd.CanFrame", "jsonschema"),
}


def candump(path):
    """(id, data) of each `(t) iface ID#DATA` line."""
    frames = []
    with open(path) as f:
        for line in f:
            parts = line.split()
            if len(parts) != 3 or "#" not in parts[2]:
                continue
            ident, data = parts[2].split("#", 1)
            frames.append((int(ident, 16), data.upper()))
    return frames


def main():
    mcap_path, log_path, expected_path = sys.argv[1:4]
    with open(expected_path) as f:
        want = json.load(f)
    errors = []

    def check(ok, what):
        if not ok:
            errors.append(what)

    counts = Counter()
    last_time = defaultdict(int)
    backwards = Counter()
    tx = []
    image_shapes = set()
    flies_sizes = set()
    commands = Counter()
    with open(mcap_path, "rb") as f:
        reader = make_reader(f, decoder_factories=[ProtobufFactory(), JsonFactory()])
        summary = reader.get_summary()
        channels = {c.topic: c for c in summary.channels.values()}
        for topic, (schema_name, schema_encoding) in SCHEMAS.items():
            c = channels.get(topic)
            check(c is not None, f"no channel {topic}")
            if c is None:
                continue
            s = summary.schemas[c.schema_id]
            check(s.name == schema_name, f"{topic}: schema {s.name}, want {schema_name}")
            check(s.encoding == schema_encoding, f"{topic}: schema encoding {s.encoding}")
        attachments = [a.name for a in reader.iter_attachments()]
        check("config.toml" in attachments, f"attachments {attachments}")
        metadata = {m.name: m.metadata for m in reader.iter_metadata()}
        check("flyd" in metadata, f"metadata {list(metadata)}")
        for schema, channel, message, decoded in reader.iter_decoded_messages(log_time_order=False):
            topic = channel.topic
            counts[topic] += 1
            if message.log_time < last_time[topic]:
                backwards[topic] += 1
            last_time[topic] = message.log_time
            if topic.endswith("/compressed"):
                errors.append(f"{topic}: a JPEG from mock cameras delivering raw frames")
            elif topic.endswith("/image"):
                image_shapes.add((decoded.width, decoded.height, decoded.encoding, len(decoded.data)))
                check(decoded.timestamp.ToNanoseconds() == message.log_time,
                      f"{topic}: header stamp != log time")
            elif topic == "/flyd/flies":
                flies_sizes.add(len(decoded.data) // decoded.point_stride)
                check([fl.name for fl in decoded.fields] == ["x", "y", "z", "fitness", "warning"],
                      "flies fields")
            elif topic == "/can/tx":
                tx.append((decoded["id"], decoded["data"]))
            elif topic == "/flyd/decision":
                commands[decoded["command"]] += 1

    check(not backwards, f"log times go backwards on {dict(backwards)}")
    dropped = want["record_dropped"]
    check(dropped == 0, f"the recorder dropped {dropped} records")
    check(counts["/camera/left/image"] == want["frames_left"],
          f"left images {counts['/camera/left/image']} != frames {want['frames_left']}")
    check(counts["/camera/right/image"] == want["frames_right"],
          f"right images {counts['/camera/right/image']} != frames {want['frames_right']}")
    check(counts["/camera/left/calibration"] >= 1 and counts["/camera/right/calibration"] >= 1,
          "calibrations")
    w, h = want["width"], want["height"]
    check(image_shapes == {(w, h, "rgb8", w * h * 3)}, f"image shapes {image_shapes}")
    check(counts["/flyd/pair"] == want["pairs"], f"pairs {counts['/flyd/pair']} != {want['pairs']}")
    flies = want["generations"] // want["flies_every"] - want["flies_skipped"]
    check(counts["/flyd/flies"] == flies,
          f"flies messages {counts['/flyd/flies']} != generations/flies_every - skipped {flies}")
    check(flies_sizes == {want["flies"]}, f"flies per cloud {flies_sizes}")
    check(counts["/flyd/perception"] == want["snapshots"],
          f"perception {counts['/flyd/perception']} != snapshots {want['snapshots']}")
    check(0 < counts["/flyd/scene"] <= want["snapshots"], "scene updates: at most one a snapshot")
    check(counts["/flyd/decision"] == want["commands"],
          f"decisions {counts['/flyd/decision']} != commands {want['commands']}")
    logged = candump(log_path)
    check(tx == logged, f"CAN tx in the recording ({len(tx)}) != the --can-log ({len(logged)})"
          + next((f": first difference at {i}: {a} vs {b}"
                  for i, (a, b) in enumerate(zip(tx, logged)) if a != b), ""))
    print(json.dumps({
        "counts": dict(counts),
        "can_tx": len(tx),
        "commands": dict(commands),
        "errors": errors,
    }))
    if errors:
        sys.exit(1)


if __name__ == "__main__":
    main()
