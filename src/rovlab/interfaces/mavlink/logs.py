"""MAVLink telemetry logs: recorded to MCAP, read back (MCAP or a ground station's .tlog) and
turned into the log that ``rovlab filter`` reads, so a real ArduSub dive can be replayed
through the estimator.

* :class:`TelemetryRecorder` writes every MAVLink message as JSON on ``/mavlink/<TYPE>`` (fields
  in MAVLink's own units, plus ``_sysid``/``_compid``) and, beside them, rovlab's own messages
  (``/rovlab/estimate``, ``/rovlab/command`` ... of rovlab.io.messages) -- one file that Foxglove
  opens and this module reads back.
* :func:`read_records` reads (time, type, fields) from an MCAP written that way or from a .tlog
  (QGroundControl, MAVProxy and BlueOS record those) through pymavlink.
* :class:`SampleMap` is the one mapping from MAVLink telemetry to the filter's measurement
  channels (SI units), used both live by the bridge and offline here:
  pressure z <- SCALED_PRESSURE2 (Bar30) depth; imu psi/phi/theta/r <- ATTITUDE;
  motion_capture x/y/z/psi <- VISION_POSITION_ESTIMATE (or LOCAL_POSITION_NED for x/y/z).
  The thruster wrench [Z, N] comes from SERVO_OUTPUT_RAW through the vehicle's thruster
  curves and configuration matrix.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from rovlab.allocation.geometry import configuration_matrix
from rovlab.interfaces.mavlink.units import STANDARD_ATMOSPHERE_HPA, depth_from_pressure
from rovlab.models.thrusters import ThrusterBank
from rovlab.params.vehicle import Vehicle

Record = tuple[float, str, dict[str, Any]]  # (UNIX time [s], MAVLink message type, fields)
MAVLINK_PREFIX = "/mavlink/"


class LogError(ValueError):
    """A log that cannot be read or holds no usable telemetry (message names the file)."""


# --------------------------------------------------------------------------------------------
# Recording
# --------------------------------------------------------------------------------------------

class TelemetryRecorder:
    """MAVLink messages and rovlab messages into one MCAP file (rovlab.io.timeseries.McapStream)."""

    def __init__(self, path: str | Path, *, metadata: Mapping[str, str] | None = None) -> None:
        from rovlab.io.timeseries import McapStream

        self.stream = McapStream(path, metadata={"recorded_by": "rovlab mavlink", **(metadata or {})})

    @property
    def path(self) -> Path:
        return self.stream.path

    def mavlink(self, msg: Any, time_unix_s: float) -> None:
        """A pymavlink message, as its fields in MAVLink units."""
        kind = msg.get_type()
        if kind == "BAD_DATA":
            return
        fields = {k: v for k, v in msg.to_dict().items() if k != "mavpackettype"}
        fields["_sysid"] = msg.get_srcSystem()
        fields["_compid"] = msg.get_srcComponent()
        self.stream.write(MAVLINK_PREFIX + kind, time_unix_s, fields)

    def rovlab(self, topic: str, time_unix_s: float, message: Mapping[str, Any]) -> None:
        self.stream.write(topic, time_unix_s, message)

    def close(self) -> None:
        self.stream.close()


# --------------------------------------------------------------------------------------------
# Reading
# --------------------------------------------------------------------------------------------

def read_records(path: str | Path) -> list[Record]:
    """The MAVLink messages of a .tlog, of an MCAP recorded by :class:`TelemetryRecorder`, or of an
    onboard DataFlash .BIN log as the MAVLink messages they correspond to (:func:`_read_bin`), in
    the order the file holds them (the order they arrived: :func:`stamp_outliers`)."""
    path = Path(path)
    if not path.is_file():
        raise LogError(f"{path}: no such file")
    suffix = path.suffix.lower()
    if suffix == ".tlog":
        records = _read_tlog(path)
    elif suffix == ".bin":
        records = _read_bin(path)
    elif suffix == ".mcap":
        try:
            from rovlab.io.timeseries import read_mcap_json

            records = [(t, topic[len(MAVLINK_PREFIX):], msg)
                       for topic, t, msg in read_mcap_json(path, prefix=MAVLINK_PREFIX, in_file_order=True)]
        except RuntimeError:
            raise
        except Exception as exc:  # noqa: BLE001 - the mcap reader raises its own types on a bad file
            raise LogError(f"{path}: not a readable MCAP file ({exc})") from None
    else:
        raise LogError(f"{path}: not a log rovlab reads: expected a .tlog (MAVLink telemetry: QGroundControl, "
                       "MAVProxy, BlueOS), a .BIN (ArduSub's onboard DataFlash log) or an .mcap recorded by "
                       "rovlab mavlink")
    if not records:
        raise LogError(f"{path}: no MAVLink messages in it")
    return records


def _read_tlog(path: Path) -> list[Record]:
    from rovlab.interfaces.mavlink import connection

    mlog = connection(str(path))
    out: list[Record] = []
    try:
        while True:
            try:
                msg = mlog.recv_match()
            except Exception:  # noqa: BLE001 - a corrupt tail ends the log
                break
            if msg is None:
                break
            kind = msg.get_type()
            if kind == "BAD_DATA":
                continue
            fields = {k: v for k, v in msg.to_dict().items() if k != "mavpackettype"}
            fields["_sysid"] = msg.get_srcSystem()
            fields["_compid"] = msg.get_srcComponent()
            out.append((float(getattr(msg, "_timestamp", 0.0)), kind, fields))
    finally:
        mlog.close()
    return out


def _read_bin(path: Path) -> list[Record]:
    """An ArduSub DataFlash log (.BIN, read by pymavlink's DFReader) as the MAVLink messages that
    carry the same quantities, so one mapping (:class:`SampleMap`) serves both: BARO of instance 1
    (the external Bar30; Press in Pa) -> SCALED_PRESSURE2.press_abs [hPa]; ATT (Roll, Pitch, Yaw in
    degrees, the AHRS attitude) -> ATTITUDE [rad], with yawspeed the latest IMU (instance 0) GyrZ
    [rad/s]; RCOU C1..C16 -> SERVO_OUTPUT_RAW servo1_raw..; PARM -> PARAM_VALUE. Times: the log's
    own (boot time, or UTC once the autopilot had it) [s]."""
    from rovlab.interfaces.mavlink import connection

    try:
        mlog = connection(str(path))
    except Exception as exc:  # noqa: BLE001 - pymavlink raises many kinds on a corrupt file
        raise LogError(f"{path}: not a readable DataFlash log ({type(exc).__name__}: {exc})") from None
    out: list[Record] = []
    gyro_z = math.nan
    try:
        while True:
            try:
                msg = mlog.recv_match(type=["BARO", "ATT", "IMU", "RCOU", "PARM"])
            except Exception:  # noqa: BLE001 - a corrupt tail ends the log
                break
            if msg is None:
                break
            kind = msg.get_type()
            t = float(getattr(msg, "_timestamp", 0.0))
            if kind == "IMU":
                if int(getattr(msg, "I", 0)) == 0:
                    gyro_z = _num(getattr(msg, "GyrZ", math.nan))
            elif kind == "BARO":
                if int(getattr(msg, "I", 0)) == 1:
                    out.append((t, "SCALED_PRESSURE2", {"press_abs": _num(msg.Press) / 100.0}))
            elif kind == "ATT":
                yaw = math.radians(_num(msg.Yaw))
                out.append((t, "ATTITUDE", {"roll": math.radians(_num(msg.Roll)), "pitch": math.radians(_num(msg.Pitch)),
                                            "yaw": math.atan2(math.sin(yaw), math.cos(yaw)), "yawspeed": gyro_z}))
            elif kind == "RCOU":
                out.append((t, "SERVO_OUTPUT_RAW", {f"servo{i}_raw": getattr(msg, f"C{i}", 0) for i in range(1, 17)}))
            elif kind == "PARM":
                out.append((t, "PARAM_VALUE", {"param_id": str(msg.Name), "param_value": _num(msg.Value)}))
    finally:
        mlog.close()
    return out


# --------------------------------------------------------------------------------------------
# Telemetry -> measurement channels and thruster wrench (SI)
# --------------------------------------------------------------------------------------------

@dataclass
class SampleMap:
    """Turns MAVLink telemetry into samples of the filter's channels and the thruster wrench."""

    vehicle: Vehicle
    channels: tuple[Any, ...]  # rovlab.estimation.model.Channel (column, kind, quantity)
    surface_hpa: float = STANDARD_ATMOSPHERE_HPA
    bank: ThrusterBank = field(init=False)
    B: np.ndarray = field(init=False)

    def __post_init__(self) -> None:
        self.bank = ThrusterBank.from_vehicle(self.vehicle)
        self.B = configuration_matrix(self.vehicle)

    def samples(self, kind: str, fields: Mapping[str, Any]) -> dict[str, float]:
        """Channel column -> value [SI] that this message gives (finite values only)."""
        out: dict[str, float] = {}
        for c in self.channels:
            v = self._value(c.kind, c.quantity, kind, fields)
            if v is not None and math.isfinite(v):
                out[c.column] = v
        return out

    def _value(self, sensor: str, quantity: str, kind: str, f: Mapping[str, Any]) -> float | None:
        if sensor == "pressure" and quantity == "z" and kind == "SCALED_PRESSURE2":
            return depth_from_pressure(_num(f.get("press_abs")), water_density=self.vehicle.water_density,
                                       gravity=self.vehicle.gravity, surface_hpa=self.surface_hpa)
        if sensor == "imu" and kind == "ATTITUDE":
            key = {"psi": "yaw", "phi": "roll", "theta": "pitch", "r": "yawspeed"}.get(quantity)
            return _num(f.get(key)) if key else None
        if sensor == "motion_capture":
            if kind == "VISION_POSITION_ESTIMATE":
                key = {"x": "x", "y": "y", "z": "z", "psi": "yaw", "phi": "roll", "theta": "pitch"}.get(quantity)
                return _num(f.get(key)) if key else None
            if kind == "LOCAL_POSITION_NED" and quantity in ("x", "y", "z"):
                return _num(f.get(quantity))
        return None

    def wrench(self, fields: Mapping[str, Any]) -> np.ndarray | None:
        """[X, Y, Z, N] [N, N m] the thrusters give for a SERVO_OUTPUT_RAW (servo i = thruster i);
        None if a pulse is missing or not a number."""
        n = len(self.bank.names)
        pwm = np.array([_num(fields.get(f"servo{i + 1}_raw")) for i in range(n)])
        if not np.all(np.isfinite(pwm)) or np.any(pwm <= 0):
            return None
        tau6 = self.B @ self.bank.force(pwm, compiled=False)
        return tau6[[0, 1, 2, 5]]


def _num(v: Any) -> float:
    try:
        return float(v)
    except (TypeError, ValueError):
        return math.nan


def vehicle_sysid(records: Iterable[Record]) -> int | None:
    """System id of the first HEARTBEAT from a submarine (MAV_TYPE_SUBMARINE = 12), if any."""
    for _t, kind, f in records:
        if kind == "HEARTBEAT" and f.get("type") == 12:
            return int(f.get("_sysid", 0))
    return None


def log_parameters(records: Iterable[Record]) -> dict[str, float]:
    """The autopilot parameters a log carries: the last PARAM_VALUE of each name (a .BIN's PARM
    become PARAM_VALUE in :func:`read_records`)."""
    out: dict[str, float] = {}
    for _t, kind, f in records:
        if kind == "PARAM_VALUE":
            name = str(f.get("param_id", "")).split("\x00", 1)[0].strip()
            v = _num(f.get("param_value"))
            if name and math.isfinite(v):
                out[name] = v
    return out


def surface_pressure_hpa(records: Iterable[Record]) -> float | None:
    """BARO2_GND_PRESS [Pa] as the vehicle reported it (PARAM_VALUE), in hPa."""
    for _t, kind, f in records:
        if kind == "PARAM_VALUE" and str(f.get("param_id", "")).strip("\x00") == "BARO2_GND_PRESS":
            v = _num(f.get("param_value"))
            if math.isfinite(v) and v > 0:
                return v / 100.0
    return None


def stamp_outliers(times: Sequence[float], limit: float, *, longest: int = 16) -> list[int]:
    """Indices of the time stamps that leave the file's order and come back: more than ``limit``
    seconds from the last stamp kept before them while one at most ``longest`` places later is
    back within ``limit`` of it. A log is written as its messages arrive (a ground station's .tlog,
    rovlab's recording), so such a stamp is corrupt, not a gap: a gap's later messages stay after
    it. A not-finite stamp is always out; the first ones are judged by the ones after them; a jump
    in the last ``longest`` messages that does not come back is kept (it cannot be told from a
    gap). Work: O(n longest) whatever the stamps."""
    t = [float(x) for x in times]
    n = len(t)
    isfinite = math.isfinite

    def near(a: float, b: float) -> bool:
        return abs(a - b) <= limit  # False for NaN

    # the first stamp that agrees with the one after it: the earlier ones are judged by it
    first = next((k for k in range(min(n, longest + 1)) if isfinite(t[k]) and (k + 1 >= n or near(t[k], t[k + 1]))),
                 None)
    if first is None:  # no two neighbours agree at the start: messages far apart (gaps), keep them
        first = next((k for k in range(n) if isfinite(t[k])), n)
    out = [k for k in range(min(first, n)) if not (first < n and near(t[k], t[first]))]
    if first >= n:
        return out
    last = t[first]
    i = first + 1
    while i < n:
        if near(t[i], last):
            last = t[i]
            i += 1
            continue
        back = next((j for j in range(i + 1, min(n, i + 1 + longest)) if near(t[j], last)), None)
        if back is None and isfinite(t[i]):  # a jump the later messages keep: a gap
            last = t[i]
            i += 1
            continue
        stop = i + 1 if back is None else back
        out.extend(range(i, stop))
        i = stop
    return out


def filter_columns(records: list[Record], vehicle: Vehicle, channels: tuple[Any, ...], h: float, *,
                   surface_hpa: float | None = None, file: str = "<log>") -> dict[str, np.ndarray]:
    """The columns ``rovlab filter`` reads (time_s, tau_X, tau_Y, tau_Z, tau_N and one per channel):
    a row at each time the vehicle sent something the filter uses, holding the samples of that time
    (NaN for the other channels) and the thruster wrench held since the last SERVO_OUTPUT_RAW. Every
    sample is kept, at any rate: the filter fuses each row at the period of its sample time h
    nearest its time, several rows of one period one after another (rovlab.estimation.streaming)."""
    sysid = vehicle_sysid(records)
    mine = [r for r in records if sysid is None or r[2].get("_sysid", sysid) == sysid]
    if surface_hpa is None:
        surface_hpa = surface_pressure_hpa(mine) or STANDARD_ATMOSPHERE_HPA
    smap = SampleMap(vehicle, channels, surface_hpa=surface_hpa)
    used_kinds = ("SCALED_PRESSURE2", "ATTITUDE", "SERVO_OUTPUT_RAW", "VISION_POSITION_ESTIMATE", "LOCAL_POSITION_NED")
    times = [t for t, kind, _ in mine if kind in used_kinds]
    if not times:
        raise LogError(f"{file}: no telemetry the filter can use (SCALED_PRESSURE2, ATTITUDE, SERVO_OUTPUT_RAW, "
                       "VISION_POSITION_ESTIMATE, LOCAL_POSITION_NED)")
    t0 = min(times)
    rows: dict[float, dict[str, float]] = {}  # time since t0 (to the microsecond) -> column -> value
    tau_at: dict[float, np.ndarray] = {}
    used = 0
    for t, kind, f in sorted(mine, key=lambda r: r[0]):
        if t < t0 or kind not in used_kinds:
            continue
        key = round(t - t0, 6)
        if kind == "SERVO_OUTPUT_RAW":
            tau = smap.wrench(f)
            if tau is not None:
                tau_at[key] = tau
                rows.setdefault(key, {})
                used += 1
            continue
        got = smap.samples(kind, f)
        if got:
            rows.setdefault(key, {}).update(got)
            used += len(got)
    if not used:
        raise LogError(f"{file}: none of its messages gives a sample of {', '.join(c.column for c in channels)}")
    keys = sorted(rows)
    n = len(keys)
    cols: dict[str, np.ndarray] = {"time_s": np.array(keys, dtype=float)}
    for c in channels:
        cols[c.column] = np.array([rows[k].get(c.column, math.nan) for k in keys], dtype=float)
    tau = np.zeros(4)  # zero-order hold; no thrust before the first SERVO_OUTPUT_RAW
    wrench = np.zeros((n, 4))
    for i, k in enumerate(keys):
        if k in tau_at:
            tau = tau_at[k]
        wrench[i] = tau
    for i, name in enumerate(("tau_X", "tau_Y", "tau_Z", "tau_N")):
        cols[name] = wrench[:, i]
    return cols


MAX_LEFT_OUT = 100  # more messages with a corrupted time stamp than this: the log's clock is broken, refused


def write_filter_log(log: str | Path, vehicle: Vehicle, model: Any, out: str | Path, *,
                     surface_hpa: float | None = None, records: list[Record] | None = None,
                     max_gap_steps: int | None = None) -> dict[str, Any]:
    """Convert a .tlog/.BIN/.mcap into the CSV ``rovlab filter`` reads (model: the filter model, for
    its channels and sample time; ``records``: the log's, if already read); returns a summary (rows,
    samples per channel, and ``left_out``: (message number from 1, type, time stamp, the stamp of
    the nearest message kept) of each message whose time stamp is corrupt).

    A corrupt stamp is one that leaves the log's order by more than the filter's gap limit
    (``max_gap_steps`` samples, default rovlab.estimation.streaming.MAX_GAP_STEPS: 1000 s at
    h = 0.1 s) and comes back (:func:`stamp_outliers`): its message is left out, since its time is
    not known; sorted in, one such stamp 12 days on made the filter predict through 12 days or
    restart there. More than ``MAX_LEFT_OUT`` of them: LogError (a broken clock, not a glitch)."""
    from rovlab.estimation.streaming import MAX_GAP_STEPS
    from rovlab.io.logwriter import write_csv

    records = read_records(log) if records is None else records
    limit = (MAX_GAP_STEPS if max_gap_steps is None else max_gap_steps) * float(model.h)
    out_of_order = stamp_outliers([r[0] for r in records], limit)
    drop = set(out_of_order)
    left_out = [(i + 1, records[i][1], records[i][0], _kept_stamp(records, drop, i)) for i in out_of_order]
    if len(left_out) > MAX_LEFT_OUT:
        raise LogError(f"{log}: {len(left_out)} messages whose time stamps leave the log's order by more than "
                       f"{limit:g} s and come back (the first: message {left_out[0][0]} ({left_out[0][1]}) stamped "
                       f"{left_out[0][2]!r} s); expected a log whose stamps follow the order its messages were "
                       f"written in: this one's clock is broken")
    if drop:
        records = [r for i, r in enumerate(records) if i not in drop]
    cols = filter_columns(records, vehicle, tuple(model.channels), float(model.h), surface_hpa=surface_hpa,
                          file=str(log))
    write_csv(out, cols, comments=[f"converted from {log} by rovlab mavlink for vehicle {vehicle.name}",
                                   "units: SI (s, m, rad, rad/s, N, N m); empty = no sample at that time"],
              exact=("time_s",))
    return {"rows": int(cols["time_s"].size), "messages": len(records) + len(left_out), "left_out": left_out,
            "gap_limit_s": limit,
            "samples": {c.column: int(np.count_nonzero(~np.isnan(cols[c.column]))) for c in model.channels}}


def _kept_stamp(records: list[Record], drop: set[int], i: int) -> float:
    """The stamp of the nearest message kept before message i (after it, for the first ones)."""
    before = next((records[k][0] for k in range(i - 1, -1, -1) if k not in drop), None)
    if before is not None:
        return before
    return next((records[k][0] for k in range(i + 1, len(records)) if k not in drop), math.nan)


def left_out_lines(log: str | Path, summary: Mapping[str, Any], *, limit: int = 5) -> list[str]:
    """What :func:`write_filter_log` left out, one line per message (the first ``limit``)."""
    gap = summary.get("gap_limit_s")
    lines = []
    for number, kind, stamp, near in summary.get("left_out", [])[:limit]:
        off = stamp - near
        lines.append(f"{log}: message {number} ({kind}): time stamp {stamp!r} s "
                     + (f"is {off:+.6g} s from the messages around it" if math.isfinite(off) else "is not a time")
                     + f"; left out (expected stamps in the order the messages were written, within {gap:g} s of "
                       "the messages around them: a corrupted time stamp)")
    more = len(summary.get("left_out", [])) - limit
    if more > 0:
        lines.append(f"{log}: {more} more message(s) with a corrupted time stamp left out")
    return lines
