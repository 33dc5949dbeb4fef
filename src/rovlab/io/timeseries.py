"""Time-series logs of a run (simulated or real) as MCAP.

A log is an ordered mapping column name -> 1-D array of equal length, with ``time_s`` first (its
CSV form is written by :func:`rovlab.io.logs.write_csv`). The MCAP file holds the same rows as JSON
messages on a few topics (the message layout of :mod:`rovlab.io.messages`), readable by Foxglove
and other robotics tools.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Mapping

import numpy as np

from rovlab.core.files import atomic_open
from rovlab.io.messages import TOPICS, rows_to_messages


def write_mcap(path: str | Path, columns: Mapping[str, np.ndarray], *, metadata: Mapping[str, str] | None = None) -> Path:
    """Write the rows as JSON messages on the topics of rovlab.io.messages (requires `mcap`)."""
    try:
        from mcap.writer import CompressionType, Writer
    except ImportError as exc:  # pragma: no cover - optional extra
        raise RuntimeError("writing MCAP needs the 'mcap' package: pip install 'rovlab[log]'") from exc
    path = Path(path)
    with atomic_open(path, "wb") as fh:
        writer = Writer(fh, compression=CompressionType.NONE)
        writer.start(profile="", library="rovlab")
        channel_ids: dict[str, int] = {}
        for topic, schema in TOPICS.items():
            sid = writer.register_schema(name=f"rovlab{topic.replace('/', '.')}", encoding="jsonschema",
                                         data=json.dumps(schema).encode())
            channel_ids[topic] = writer.register_channel(topic=topic, message_encoding="json", schema_id=sid)
        if metadata:
            writer.add_metadata("rovlab", {k: str(v) for k, v in metadata.items()})
        for seq, (topic, t, msg) in enumerate(rows_to_messages(columns)):
            stamp = int(round(t * 1e9))
            writer.add_message(channel_ids[topic], log_time=stamp, data=json.dumps(msg).encode(),
                               publish_time=stamp, sequence=seq)
        writer.finish()
    return path
