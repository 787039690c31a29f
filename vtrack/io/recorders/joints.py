"""Sources of the hand's joint states for the tactile recorder.

A source has ``names`` (joint order of the ``joints/q`` columns) and ``poll(now)`` returning the
new samples ``[(t, q)]`` (t in the recorder's clock, s; q in rad) available at recorder time ``now``.

- :class:`CallbackJointSource`: calls a user function each time the recorder polls.
- :class:`CsvJointSource`: a CSV file ``t, <joint names...>`` (t relative to the recording start,
  or absolute with ``absolute_time=True``); rows are released as recording time passes them.
- :class:`RosJointSource`: subscribes to a ``sensor_msgs/JointState`` topic with rclpy (ROS 2) or
  rospy (ROS 1), whichever is installed; stamps are ROS (wall-clock) time, matching the recorder's
  ``time.time()`` clock for live devices.
"""

from __future__ import annotations

import csv
import threading
from collections import deque
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from vtrack.errors import InputError


class JointSource:
    names: list[str]

    def start(self, t0: float) -> None:
        """Called when recording starts; ``t0`` is the recorder clock at start (s)."""

    def poll(self, now: float) -> list[tuple[float, np.ndarray]]:
        raise NotImplementedError

    def close(self) -> None:
        pass


class CallbackJointSource(JointSource):
    """``fn() -> q`` (rad, len(names)), sampled at each poll with the poll time as timestamp."""

    def __init__(self, fn: Callable[[], Sequence[float]], names: Sequence[str]) -> None:
        self.fn = fn
        self.names = list(names)

    def poll(self, now: float) -> list[tuple[float, np.ndarray]]:
        q = np.asarray(self.fn(), dtype=np.float64).reshape(-1)
        if q.shape != (len(self.names),) or not np.all(np.isfinite(q)):
            return []
        return [(now, q)]


class CsvJointSource(JointSource):
    """Joint states from a CSV with header ``t,<name1>,<name2>,...`` (t in s, q in rad)."""

    def __init__(self, path: str | Path, absolute_time: bool = False) -> None:
        self.path = Path(path)
        if not self.path.exists():
            raise InputError("joint-state CSV does not exist", path=self.path)
        with open(self.path, newline="") as f:
            rows = list(csv.reader(f))
        if not rows or len(rows[0]) < 2 or rows[0][0].strip().lower() not in ("t", "time", "timestamp"):
            raise InputError(
                "joint-state CSV needs a header 't,<joint names...>'",
                path=self.path,
                got=rows[0] if rows else "empty file",
            )
        self.names = [c.strip() for c in rows[0][1:]]
        data = []
        for i, r in enumerate(rows[1:], start=2):
            if not r:
                continue
            try:
                vals = [float(x) for x in r]
            except ValueError:
                raise InputError(f"non-numeric value on line {i}", path=self.path) from None
            if len(vals) != len(self.names) + 1:
                raise InputError(f"line {i} has {len(vals)} columns", path=self.path, expected=str(len(self.names) + 1))
            data.append(vals)
        arr = np.asarray(data, dtype=np.float64).reshape(-1, len(self.names) + 1)
        if not np.all(np.isfinite(arr)):
            raise InputError("NaN/Inf in joint-state CSV", path=self.path)
        if len(arr) > 1 and np.any(np.diff(arr[:, 0]) <= 0):
            raise InputError("times must be strictly increasing", path=self.path, field="t")
        self.t = arr[:, 0]
        self.q = arr[:, 1:]
        self.absolute = absolute_time
        self._i = 0
        self._t0 = 0.0

    def start(self, t0: float) -> None:
        self._t0 = 0.0 if self.absolute else t0

    def poll(self, now: float) -> list[tuple[float, np.ndarray]]:
        out = []
        while self._i < len(self.t) and self.t[self._i] + self._t0 <= now:
            out.append((float(self.t[self._i] + self._t0), self.q[self._i]))
            self._i += 1
        return out


class RosJointSource(JointSource):
    """Subscribe to a ``sensor_msgs/JointState`` topic (ROS 2 rclpy, else ROS 1 rospy)."""

    def __init__(self, topic: str, names: Sequence[str] | None = None) -> None:
        self.topic = topic
        self.names = list(names or [])
        self._buf: deque = deque(maxlen=10000)
        self._lock = threading.Lock()
        self._node = None
        try:
            import rclpy  # type: ignore[import-not-found]
            from sensor_msgs.msg import JointState  # type: ignore[import-not-found]

            rclpy.init(args=None)
            self._node = rclpy.create_node("vtrack_joint_recorder")
            self._node.create_subscription(JointState, topic, self._cb, 100)
            self._thread = threading.Thread(target=rclpy.spin, args=(self._node,), daemon=True)
            self._thread.start()
        except ImportError:
            try:
                import rospy  # type: ignore[import-not-found]
                from sensor_msgs.msg import JointState  # type: ignore[import-not-found]

                rospy.init_node("vtrack_joint_recorder", anonymous=True, disable_signals=True)
                rospy.Subscriber(topic, JointState, self._cb, queue_size=100)
            except ImportError:
                raise InputError(
                    "neither rclpy (ROS 2) nor rospy (ROS 1) is installed; source your ROS "
                    "environment or use --joints-csv",
                    field="--joints-topic",
                    got=topic,
                ) from None

    def _cb(self, msg) -> None:
        st = msg.header.stamp
        t = float(getattr(st, "sec", getattr(st, "secs", 0))) + 1e-9 * float(
            getattr(st, "nanosec", getattr(st, "nsecs", 0))
        )
        names = list(msg.name)
        q = np.asarray(msg.position, dtype=np.float64)
        with self._lock:
            if not self.names:
                self.names = names
            if names != self.names:
                if sorted(names) != sorted(self.names):
                    return
                idx = {n: i for i, n in enumerate(names)}
                q = q[[idx[n] for n in self.names]]
            self._buf.append((t, q))

    def poll(self, now: float) -> list[tuple[float, np.ndarray]]:
        with self._lock:
            out = list(self._buf)
            self._buf.clear()
        return out

    def close(self) -> None:
        if self._node is not None:
            self._node.destroy_node()
