#!/usr/bin/env python3
"""An independent check of a terranav MCAP recording (tests/record.rs runs it).

Reads the file with the `mcap` Python package (not our Rust reader), and checks:
- the summary: every channel's schema name and encoding, and that the statistics' message counts
  equal what a full read finds per channel;
- every message validates against its schema: Foxglove's from the npm package @foxglove/schemas
  (dumped to JSON by node, passed as --foxglove-schemas), terranav's from the schema the file
  embeds; the schemas the file embeds for Foxglove's names equal the npm package's.

  record_check.py FILE --foxglove-schemas SCHEMAS.json [--expect TOPIC=SCHEMA ...] [--min TOPIC=N ...]
  record_check.py FILE --cut    (a file whose writer was killed: count what reads)

Prints one JSON line: channels, counts, messages validated.
"""

import argparse
import json
import sys

from mcap.reader import make_reader
from mcap.stream_reader import StreamReader
from mcap.records import Message, Channel, Schema
import jsonschema


def cut(path):
    """Reads a file whose writer was killed, front to back, until it ends."""
    counts = {}
    channels = {}
    error = None
    with open(path, "rb") as f:
        try:
            for rec in StreamReader(f, skip_magic=False).records:
                if isinstance(rec, Channel):
                    channels[rec.id] = rec.topic
                elif isinstance(rec, Message):
                    t = channels[rec.channel_id]
                    counts[t] = counts.get(t, 0) + 1
                    json.loads(rec.data)
        except Exception as e:  # the end of a cut file
            error = f"{type(e).__name__}: {e}"
    print(json.dumps({"messages": sum(counts.values()), "counts": counts, "ended_with": error}))


def check(path, fox_path, expect, minimum):
    with open(fox_path) as f:
        fox = json.load(f)
    with open(path, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None, "no summary: the file was not closed"
        assert summary.statistics is not None, "no statistics in the summary"
        schemas = summary.schemas
        chans = summary.channels
        info = {}
        validators = {}
        for cid, ch in chans.items():
            sc = schemas[ch.schema_id]
            assert ch.message_encoding == "json", (ch.topic, ch.message_encoding)
            assert sc.encoding == "jsonschema", (ch.topic, sc.encoding)
            embedded = json.loads(sc.data)
            assert embedded.get("title") == sc.name, (sc.name, embedded.get("title"))
            if sc.name.startswith("foxglove."):
                short = sc.name.split(".", 1)[1]
                assert short in fox, f"{sc.name} is not in @foxglove/schemas"
                assert embedded == fox[short], f"{sc.name}: the embedded schema differs from @foxglove/schemas"
                schema = fox[short]
            else:
                assert sc.name.startswith("terranav."), sc.name
                schema = embedded
            jsonschema.Draft7Validator.check_schema(schema)
            validators[cid] = jsonschema.Draft7Validator(schema)
            info[ch.topic] = sc.name
        for topic, name in expect:
            assert info.get(topic) == name, f"{topic}: {info.get(topic)} != {name}"
        counts = {}
        validated = 0
        for sc, ch, msg in reader.iter_messages():
            doc = json.loads(msg.data)
            errors = sorted(validators[ch.id].iter_errors(doc), key=lambda e: e.path)
            assert not errors, f"{ch.topic} message at {msg.log_time}: {errors[0].message} at {list(errors[0].path)}"
            counts[ch.topic] = counts.get(ch.topic, 0) + 1
            validated += 1
        stats = summary.statistics.channel_message_counts
        for cid, ch in chans.items():
            assert stats.get(cid, 0) == counts.get(ch.topic, 0), (ch.topic, stats.get(cid), counts.get(ch.topic))
        assert summary.statistics.message_count == validated
        assert len(summary.chunk_indexes) > 1, "chunked, with an index"
        for topic, n in minimum:
            assert counts.get(topic, 0) >= n, f"{topic}: {counts.get(topic, 0)} messages < {n}"
    print(json.dumps({"channels": info, "counts": counts, "validated": validated,
                      "chunks": len(summary.chunk_indexes)}))


def pairs(items, conv):
    out = []
    for it in items or []:
        k, v = it.split("=", 1)
        out.append((k, conv(v)))
    return out


def main():
    p = argparse.ArgumentParser()
    p.add_argument("file")
    p.add_argument("--foxglove-schemas")
    p.add_argument("--expect", action="append")
    p.add_argument("--min", action="append")
    p.add_argument("--cut", action="store_true")
    a = p.parse_args()
    if a.cut:
        cut(a.file)
        return
    check(a.file, a.foxglove_schemas, pairs(a.expect, str), pairs(a.min, int))


if __name__ == "__main__":
    try:
        main()
    except AssertionError as e:
        print(f"record_check: {e}", file=sys.stderr)
        sys.exit(1)
