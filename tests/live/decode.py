#!/usr/bin/env python3
"""Decodes what tests/live/client.js received with Python's protobuf (the descriptors the
server advertised) and json, and prints a summary as JSON; exits 1 if anything is missing.

    decode.py CLIENT_OUTPUT.json
"""
import base64
import json
import sys

from google.protobuf import descriptor_pb2, descriptor_pool, message_factory


def protobuf_class(schema_name, schema_b64):
    fds = descriptor_pb2.FileDescriptorSet.FromString(base64.b64decode(schema_b64))
    pool = descriptor_pool.DescriptorPool()
    for f in fds.file:
        pool.Add(f)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(schema_name))


def main():
    received = json.load(open(sys.argv[1]))
    out, errors = {}, []
    for topic, t in received["topics"].items():
        msgs = [base64.b64decode(m["data"]) for m in t["messages"]]
        if t["encoding"] == "protobuf":
            cls = protobuf_class(t["schemaName"], t["schema"])
            decoded = [cls.FromString(m) for m in msgs]
            first = decoded[0] if decoded else None
            if t["schemaName"] == "foxglove.RawImage" and first is not None:
                out[topic] = {"width": first.width, "height": first.height,
                              "encoding": first.encoding, "bytes": len(first.data),
                              "count": len(decoded)}
                if len(first.data) != first.width * first.height * 3:
                    errors.append(f"{topic}: {len(first.data)} bytes")
            elif t["schemaName"] == "foxglove.PointCloud" and first is not None:
                out[topic] = {"points": len(first.data) // first.point_stride,
                              "fields": [f.name for f in first.fields], "count": len(decoded)}
            else:
                out[topic] = {"count": len(decoded)}
        else:
            decoded = [json.loads(m) for m in msgs]
            out[topic] = {"count": len(decoded), "first": decoded[0] if decoded else None}
    print(json.dumps({"server": received["server"], "topics": out, "errors": errors}))
    if errors:
        sys.exit(1)


if __name__ == "__main__":
    main()
