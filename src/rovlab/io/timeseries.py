"""Time-series logs of a run (simulated or real) as MCAP, for Foxglove and ROS 2 tools.

A log is an ordered mapping column name -> 1-D array of equal length, with ``time_s`` first (its
CSV form is written by :func:`rovlab.io.logs.write_csv`). The MCAP file holds the same rows as JSON
messages on a few topics (the message layout of :mod:`rovlab.io.messages`), readable by Foxglove
and other robotics tools.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from rovlab.core.files import atomic_open
from rovlab.io import ros2msg
from rovlab.io.messages import TOPICS, rows_to_messages


def write_mcap(path: str | Path, columns: Mapping[str, np.ndarray], *, metadata: Mapping[str, str] | None = None,
               start_time_s: float | None = None) -> Path:
    """Write the rows to MCAP (requires `mcap`): every column as JSON messages on the topics of
    rovlab.io.messages (JSON Schema declared: Foxglove plots any field), and the poses and
    velocities as ROS 2 nav_msgs/Odometry
    (/rovlab/odometry/truth, /rovlab/odometry/estimate with the filter's variances) and the
    wrench as geometry_msgs/WrenchStamped (/rovlab/wrench), which Foxglove's 3D panel and ROS 2
    tools open without configuration (CDR encoded by rovlab.io.ros2msg). Log times are
    wall-clock: ``start_time_s`` (UNIX seconds of the run's start; default now) + time_s."""
    try:
        from mcap.writer import CompressionType, Writer
    except ImportError as exc:  # pragma: no cover - optional extra
        raise RuntimeError("writing MCAP needs the 'mcap' package: pip install 'rovlab[log]'") from exc
    t0_ns = int(round((time.time() if start_time_s is None else float(start_time_s)) * 1e9))
    path = Path(path)
    with atomic_open(path, "wb") as fh:
        writer = Writer(fh, compression=CompressionType.NONE)
        writer.start(profile="", library="rovlab")
        channel_ids: dict[str, int] = {}
        for topic, schema in TOPICS.items():
            sid = writer.register_schema(name="rovlab." + topic.rsplit("/", 1)[-1], encoding="jsonschema",
                                         data=json.dumps(schema).encode())
            channel_ids[topic] = writer.register_channel(topic=topic, message_encoding="json", schema_id=sid)
        for topic, datatype in ROS2_TOPICS.items():
            sid = writer.register_schema(name=datatype, encoding="ros2msg", data=ros2msg.DEFINITIONS[datatype].encode())
            channel_ids[topic] = writer.register_channel(topic=topic, message_encoding="cdr", schema_id=sid)
        meta = {"start_time_unix_s": f"{t0_ns / 1e9:.9f}", "world_frame": ros2msg.WORLD_FRAME,
                "body_frame": ros2msg.BODY_FRAME, **{k: str(v) for k, v in (metadata or {}).items()}}
        writer.add_metadata("rovlab", meta)
        seq = 0
        for topic, t, msg in rows_to_messages(columns):
            stamp = t0_ns + int(round(t * 1e9))
            writer.add_message(channel_ids[topic], log_time=stamp, data=json.dumps(msg).encode(),
                               publish_time=stamp, sequence=seq)
            seq += 1
            for ros_topic, data in _ros2_messages(topic, stamp, msg):
                writer.add_message(channel_ids[ros_topic], log_time=stamp, data=data, publish_time=stamp, sequence=seq)
                seq += 1
        writer.finish()
    return path


ROS2_TOPICS = {
    "/rovlab/odometry/truth": ros2msg.ODOMETRY,
    "/rovlab/odometry/estimate": ros2msg.ODOMETRY,
    "/rovlab/wrench": ros2msg.WRENCH_STAMPED,
}


def _ros2_messages(topic: str, stamp: int, msg: Mapping[str, Any]):
    """The ROS 2 messages (CDR bytes) that go with one rovlab message."""
    if topic == "/rovlab/truth":
        yield "/rovlab/odometry/truth", ros2msg.odometry_cdr(stamp, msg["state"])
    elif topic == "/rovlab/estimate":
        yield "/rovlab/odometry/estimate", ros2msg.odometry_cdr(stamp, msg["state"], msg.get("variance"))
    elif topic == "/rovlab/command" and msg.get("tau"):
        yield "/rovlab/wrench", ros2msg.wrench_stamped_cdr(stamp, msg["tau"])


class McapStream:
    """An MCAP file written message by message (a live recording: a vehicle bridge's telemetry).

    Every topic carries JSON messages; a topic's JSON Schema is given with its first message (or
    a permissive one). The file is written in place as messages arrive, in chunks of
    ``chunk_size`` bytes, so a recording that is closed (:meth:`close`, also on Ctrl-C through
    the caller's ``finally``) is complete, and one whose process is killed keeps the chunks
    already written. Requires `mcap` (``pip install 'rovlab[log]'``).
    """

    def __init__(self, path: str | Path, *, metadata: Mapping[str, str] | None = None,
                 chunk_size: int = 256 * 1024) -> None:
        try:
            from mcap.writer import CompressionType, Writer
        except ImportError as exc:  # pragma: no cover - optional extra
            raise RuntimeError("writing MCAP needs the 'mcap' package: pip install 'rovlab[log]'") from exc
        self.path = Path(path)
        self._fh = open(self.path, "wb")  # noqa: SIM115 - closed in close()
        self._writer = Writer(self._fh, compression=CompressionType.NONE, chunk_size=chunk_size)
        self._writer.start(profile="", library="rovlab")
        self._writer.add_metadata("rovlab", {k: str(v) for k, v in (metadata or {}).items()})
        self._channels: dict[str, int] = {}
        self._seq = 0
        self.count = 0
        self.closed = False

    def write(self, topic: str, time_unix_s: float, message: Mapping[str, Any], *,
              schema: Mapping[str, Any] | None = None) -> None:
        """One JSON message on a topic, stamped with a UNIX time [s]."""
        if self.closed:
            raise ValueError(f"{self.path}: recording already closed")
        cid = self._channels.get(topic)
        if cid is None:
            sch = schema if schema is not None else TOPICS.get(topic, {"type": "object"})
            sid = self._writer.register_schema(name=topic.strip("/").replace("/", "."), encoding="jsonschema",
                                               data=json.dumps(sch).encode())
            cid = self._channels[topic] = self._writer.register_channel(topic=topic, message_encoding="json",
                                                                        schema_id=sid)
        stamp = int(round(time_unix_s * 1e9))
        data = json.dumps(_finite(message), allow_nan=False, default=_json_default).encode()
        self._writer.add_message(cid, log_time=stamp, data=data, publish_time=stamp, sequence=self._seq)
        self._seq += 1
        self.count += 1

    def close(self) -> None:
        """Finish the file (summary and index); safe to call twice."""
        if self.closed:
            return
        self.closed = True
        try:
            self._writer.finish()
        finally:
            self._fh.close()


def _finite(value: Any) -> Any:
    """NaN and infinities as null (JSON has neither), inside dicts and lists too."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, Mapping):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite(v) for v in value]
    return value


def _json_default(value: Any) -> Any:
    if isinstance(value, (bytes, bytearray)):
        return value.decode("latin-1")
    if isinstance(value, np.generic):
        return value.item()
    return str(value)


def mcap_topics(path: str | Path) -> set[str]:
    """The topics of an MCAP file (from its summary, or by reading it through if it has none)."""
    from mcap.reader import NonSeekingReader, make_reader

    with open(path, "rb") as fh:
        try:
            summary = make_reader(fh).get_summary()
        except Exception:  # noqa: BLE001 - no usable summary: read it through
            summary = None
        if summary is not None:
            return {c.topic for c in summary.channels.values()}
        fh.seek(0)
        topics: set[str] = set()
        try:
            for _schema, channel, _message in NonSeekingReader(fh).iter_messages():
                topics.add(channel.topic)
        except Exception:  # noqa: BLE001 - the cut-off end of a recording
            pass
        return topics


def read_mcap_json(path: str | Path, *, prefix: str = "/") -> Any:
    """(topic, UNIX time [s], message dict) of the JSON messages on topics starting with prefix,
    in log-time order. Requires `mcap`."""
    try:
        from mcap.reader import make_reader
    except ImportError as exc:  # pragma: no cover - optional extra
        raise RuntimeError("reading MCAP needs the 'mcap' package: pip install 'rovlab[log]'") from exc
    from mcap.reader import NonSeekingReader

    with open(path, "rb") as fh:
        try:  # a finished file: its index gives log-time order
            items = list(make_reader(fh).iter_messages(log_time_order=True))
        except Exception:  # noqa: BLE001 - a recording cut short (no summary): read it front to back
            fh.seek(0)
            items = []
            try:
                for item in NonSeekingReader(fh).iter_messages():
                    items.append(item)
            except Exception:  # noqa: BLE001 - the cut-off end
                pass
            items.sort(key=lambda m: m[2].log_time)
        for _schema, channel, message in items:
            if channel.message_encoding != "json" or not channel.topic.startswith(prefix):
                continue
            yield channel.topic, message.log_time / 1e9, json.loads(message.data)


# JSON topic -> (field, column prefix) of the columns it carries (the inverse of rows_to_messages)
_COLUMNS_OF = {
    "/rovlab/truth": (("state", "true_"),),
    "/rovlab/estimate": (("state", "est_"), ("variance", "var_")),
    "/rovlab/measurement": (("values", "meas_"),),
    "/rovlab/reference": (("state", "ref_"),),
    "/rovlab/command": (("tau", "tau_"), ("pwm_us", "pwm_"), ("controller", "ctrl_")),
}


def read_mcap_columns(path: str | Path) -> dict[str, np.ndarray]:
    """The numeric time-series columns (time_s, true_*, est_*, var_*, meas_*, ref_*, tau_*,
    pwm_*, ctrl_*) of an MCAP log with rovlab's JSON topics -- written by :func:`write_mcap` or
    recorded by the vehicle node -- one row per message time; NaN where a row has no value
    (e.g. no sample of a sensor). ConfigError for a file that is not such a log."""
    from rovlab.params.validate import ConfigError, Problem

    try:
        from mcap.reader import make_reader
    except ImportError as exc:  # pragma: no cover - optional extra
        raise RuntimeError("reading MCAP needs the 'mcap' package: pip install 'rovlab[log]'") from exc
    rows: dict[float, dict[str, float]] = {}
    names: dict[str, None] = {}
    try:
        with open(path, "rb") as fh:
            for _schema, channel, message in make_reader(fh).iter_messages(topics=list(_COLUMNS_OF)):
                if channel.message_encoding != "json":
                    continue
                msg = json.loads(message.data)
                row = rows.setdefault(float(msg["t"]), {})
                for field, prefix in _COLUMNS_OF[channel.topic]:
                    for k, v in (msg.get(field) or {}).items():
                        names[prefix + k] = None
                        row[prefix + k] = float("nan") if v is None else float(v)
    except FileNotFoundError:
        raise ConfigError([Problem(str(path), "", "no such file", "an existing MCAP log")], "log") from None
    except Exception as exc:  # the mcap reader raises its own errors for a damaged file
        raise ConfigError([Problem(str(path), "", f"unreadable ({type(exc).__name__}: {exc})",
                                   "an MCAP log with rovlab's JSON topics")], "log") from None
    if not rows:
        raise ConfigError([Problem(str(path), "", "no rovlab messages",
                                   "an MCAP log with rovlab's topics (" + ", ".join(_COLUMNS_OF) + ")")], "log")
    times = sorted(rows)
    out: dict[str, np.ndarray] = {"time_s": np.array(times)}
    for name in names:
        out[name] = np.array([rows[t].get(name, np.nan) for t in times])
    return out
