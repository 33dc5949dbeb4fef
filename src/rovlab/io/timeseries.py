"""Time-series logs of a run (simulated or real) as MCAP, for ROS 2 tools, Foxglove and replay.

A log is an ordered mapping column name -> 1-D array of equal length, with ``time_s`` first (its
CSV form is written by :func:`rovlab.io.logwriter.write_csv`). A run's MCAP is two files:

* ``RUN.mcap``, a ROS 2 bag: only ROS 2 messages (CDR, ``ros2msg`` definitions, profile
  ``ros2``) -- odometry of the truth and of the estimate, the wrench, /tf -- which rosbags,
  ``ros2 bag`` and Foxglove open as they are;
* ``RUN.rovlab.mcap`` (:func:`series_path`), the same rows as JSON messages on rovlab's topics
  (:mod:`rovlab.io.messages`): every column, including what no standard ROS message holds
  (sensor status, measurements per sensor, controller state), for Foxglove's plots,
  ``rovlab filter`` and :func:`read_mcap_columns`.
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

SERIES_SUFFIX = ".rovlab.mcap"


def series_path(path: str | Path) -> Path:
    """Where rovlab's series (JSON topics) of a ROS 2 bag ``RUN.mcap`` go: ``RUN.rovlab.mcap``
    beside it."""
    path = Path(path)
    stem = path.name[:-len(".mcap")] if path.name.endswith(".mcap") else path.name
    return path.with_name(stem + SERIES_SUFFIX)


def write_mcap(path: str | Path, columns: Mapping[str, np.ndarray], *, metadata: Mapping[str, str] | None = None,
               start_time_s: float | None = None) -> Path:
    """A run's MCAP files (requires `mcap` and `mcap-ros2-support`): the ROS 2 bag at ``path``
    (:func:`write_ros2_bag`) and rovlab's series beside it (:func:`series_path`,
    :func:`write_series_mcap`). Log times are wall-clock: ``start_time_s`` (UNIX seconds of the
    run's start; default now) + time_s. Returns ``path``."""
    start = time.time() if start_time_s is None else float(start_time_s)
    series = series_path(path)
    write_series_mcap(series, columns, metadata={**(metadata or {}), "ros2_bag": Path(path).name}, start_time_s=start)
    return write_ros2_bag(path, columns, metadata={**(metadata or {}), "series": series.name}, start_time_s=start)


def write_series_mcap(path: str | Path, columns: Mapping[str, np.ndarray], *,
                      metadata: Mapping[str, str] | None = None, start_time_s: float | None = None) -> Path:
    """Every column as JSON messages on the topics of rovlab.io.messages (JSON Schema declared:
    Foxglove plots any field; ``rovlab filter`` and :func:`read_mcap_columns` read them back)."""
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
        writer.add_metadata("rovlab", {"start_time_unix_s": f"{t0_ns / 1e9:.9f}",
                                       **{k: str(v) for k, v in (metadata or {}).items()}})
        for seq, (topic, t, msg) in enumerate(rows_to_messages(columns)):
            stamp = t0_ns + int(round(t * 1e9))
            writer.add_message(channel_ids[topic], log_time=stamp, data=json.dumps(msg).encode(),
                               publish_time=stamp, sequence=seq)
        writer.finish()
    return path


ROS2_TOPICS = {
    "/rovlab/odometry/truth": ros2msg.ODOMETRY,
    "/rovlab/odometry/estimate": ros2msg.ODOMETRY,
    "/rovlab/wrench": ros2msg.WRENCH_STAMPED,
    "/tf": ros2msg.TF_MESSAGE,
}


def write_ros2_bag(path: str | Path, columns: Mapping[str, np.ndarray], *,
                   metadata: Mapping[str, str] | None = None, start_time_s: float | None = None) -> Path:
    """A ROS 2 bag in MCAP (profile ``ros2``, CDR messages with their ``ros2msg`` definitions:
    rosbags, ``ros2 bag`` and Foxglove open it) of a run's poses, velocities and wrench, in ROS's
    frames (rovlab.io.ros2msg: ``map`` ENU, ``base_link`` FLU): nav_msgs/Odometry on
    /rovlab/odometry/truth (exact: zero covariance) and /rovlab/odometry/estimate (the filter's
    variances; UNESTIMATED_VARIANCE for what it does not estimate), geometry_msgs/WrenchStamped on
    /rovlab/wrench (the achieved wrench) and tf2_msgs/TFMessage on /tf (map -> base_link from the
    estimate, or from the truth for a log without one)."""
    try:
        from mcap.writer import CompressionType
        from mcap_ros2.writer import Writer
    except ImportError as exc:  # pragma: no cover - optional extra
        raise RuntimeError("writing a ROS 2 bag needs mcap and mcap-ros2-support: pip install 'rovlab[log]'") from exc
    t0_ns = int(round((time.time() if start_time_s is None else float(start_time_s)) * 1e9))
    path = Path(path)
    tf_from = "/rovlab/estimate" if any(k.startswith("est_") for k in columns) else "/rovlab/truth"
    with atomic_open(path, "wb") as fh:
        writer = Writer(fh, compression=CompressionType.NONE)
        schemas = {t: writer.register_msgdef(t, ros2msg.DEFINITIONS[t]) for t in set(ROS2_TOPICS.values())}
        writer.add_metadata("rovlab", {"start_time_unix_s": f"{t0_ns / 1e9:.9f}", "world_frame": ros2msg.WORLD_FRAME,
                                       "body_frame": ros2msg.BODY_FRAME,
                                       **{k: str(v) for k, v in (metadata or {}).items()}})
        seq = 0
        for topic, t, msg in rows_to_messages(columns):
            stamp = t0_ns + int(round(t * 1e9))
            for ros_topic, ros_msg in _ros2_messages(topic, stamp, msg, tf=topic == tf_from):
                writer.write_message(ros_topic, schemas[ROS2_TOPICS[ros_topic]], ros_msg, log_time=stamp,
                                     publish_time=stamp, sequence=seq)
                seq += 1
        writer.finish()
    return path


def _values(group: Mapping[str, Any] | None) -> dict[str, float]:
    """A message's numbers with null (NaN in the log) as NaN."""
    return {k: math.nan if v is None else float(v) for k, v in (group or {}).items()}


def _ros2_messages(topic: str, stamp: int, msg: Mapping[str, Any], *, tf: bool):
    """The ROS 2 messages (dicts) that go with one rovlab message."""
    if topic in ("/rovlab/truth", "/rovlab/estimate"):
        state = _values(msg.get("state"))
        if topic == "/rovlab/truth":
            content = ros2msg.odometry_content(state)
        else:
            variance = _values(msg.get("variance"))
            states = tuple(variance)
            content = ros2msg.odometry_content(state, np.diag([variance[s] for s in states]), states)
        yield "/rovlab/odometry/" + topic.rsplit("/", 1)[-1], ros2msg.odometry(stamp, content)
        if tf and (transform := ros2msg.body_transform(stamp, content)) is not None:
            yield "/tf", ros2msg.tf_message([transform])
    elif topic == "/rovlab/command" and msg.get("tau"):
        tau = _values(msg["tau"])
        yield "/rovlab/wrench", ros2msg.wrench_stamped(stamp, [tau.get(k, 0.0) for k in "XYZN"])


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


def read_mcap_json(path: str | Path, *, prefix: str = "/", in_file_order: bool = False) -> Any:
    """(topic, UNIX time [s], message dict) of the JSON messages on topics starting with prefix,
    in log-time order (``in_file_order``: in the order they were written, so that a corrupted
    log time can be told from its neighbours). Requires `mcap`."""
    try:
        from mcap.reader import make_reader
    except ImportError as exc:  # pragma: no cover - optional extra
        raise RuntimeError("reading MCAP needs the 'mcap' package: pip install 'rovlab[log]'") from exc
    from mcap.reader import NonSeekingReader

    with open(path, "rb") as fh:
        try:  # a finished file: its index gives log-time order
            items = list(make_reader(fh).iter_messages(log_time_order=not in_file_order))
        except Exception:  # noqa: BLE001 - a recording cut short (no summary): read it front to back
            fh.seek(0)
            items = []
            try:
                for item in NonSeekingReader(fh).iter_messages():
                    items.append(item)
            except Exception:  # noqa: BLE001 - the cut-off end
                pass
            if not in_file_order:
                items.sort(key=lambda m: m[2].log_time)
        for _schema, channel, message in items:
            if channel.message_encoding != "json" or not channel.topic.startswith(prefix):
                continue
            yield channel.topic, message.log_time / 1e9, json.loads(message.data)


def _json_topics(path: str | Path) -> bool:
    """Whether an MCAP file has JSON channels (from its summary; True when it has none to read,
    so that the caller reads the file itself and reports what is wrong with it)."""
    from mcap.reader import make_reader

    try:
        with open(path, "rb") as fh:
            summary = make_reader(fh).get_summary()
    except Exception:  # noqa: BLE001 - a damaged file: its own reader says why
        return True
    if summary is None:
        return True
    return any(c.message_encoding == "json" for c in summary.channels.values())


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
    (e.g. no sample of a sensor). Given a ROS 2 bag of rovlab's (no JSON topics), its series file
    beside it (:func:`series_path`) is read. ConfigError for a file that is not such a log."""
    from rovlab.params.validate import ConfigError, Problem

    companion = series_path(path)
    if companion != Path(path) and companion.exists() and Path(path).exists() and not _json_topics(path):
        path = companion

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
                                   "an MCAP log with rovlab's topics (" + ", ".join(_COLUMNS_OF) + "), or a ROS 2 bag of "
                                   f"rovlab's with its series file {series_path(path).name} beside it")], "log")
    times = sorted(rows)
    out: dict[str, np.ndarray] = {"time_s": np.array(times)}
    for name in names:
        out[name] = np.array([rows[t].get(name, np.nan) for t in times])
    return out
