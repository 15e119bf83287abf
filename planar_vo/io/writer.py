"""Writing ROS 2 bags (MCAP or sqlite3) with rosbags: odometry, any Jazzy message, raw copies.

Writers never overwrite: an existing output path is refused before anything is touched. On an
exception inside the ``with`` block the bag is still closed properly (index and
``metadata.yaml`` written), so everything written up to the error stays readable.
"""

from __future__ import annotations

import logging
from contextlib import suppress
from pathlib import Path
from types import TracebackType
from typing import Any

import numpy as np
from rosbags.interfaces import ConnectionExtRosbag2, MessageDefinitionFormat
from rosbags.rosbag2 import StoragePlugin, Writer

from planar_vo.errors import BagError
from planar_vo.io.reader import TYPESTORE, BagReader, one_line
from planar_vo.ros.messages import odometry_message

__all__ = ['ODOMETRY_TYPE', 'STORAGES', 'BagWriter', 'OdometryBagWriter']

log = logging.getLogger(__name__)

ODOMETRY_TYPE = 'nav_msgs/msg/Odometry'
STORAGES = {'mcap': StoragePlugin.MCAP, 'sqlite3': StoragePlugin.SQLITE3}
_BAG_VERSION = 9                       # rosbag2 metadata version written by Jazzy


class BagWriter:
    """A new ROS 2 bag (context manager): typed messages, odometry and raw copies.

    Args:
        path: the bag directory to create; must not exist.
        storage: ``'mcap'`` or ``'sqlite3'``.

    Raises:
        BagError: `path` exists (nothing is touched) or `storage` is unknown.
    """

    def __init__(self, path: str | Path, *, storage: str = 'mcap') -> None:
        self.path = Path(path)
        if storage not in STORAGES:
            raise BagError(f"storage: expected one of {list(STORAGES)}, got '{storage}'")
        if self.path.exists() or self.path.is_symlink():
            raise BagError(f"out: '{self.path}' already exists; refusing to overwrite it "
                           f'(remove it or choose another path)')
        self.storage = storage
        self.counts: dict[str, int] = {}
        self._writer: Writer | None = None
        self._connections: dict[str, Any] = {}

    # -- context -----------------------------------------------------------------------------

    def __enter__(self) -> BagWriter:
        self.open()
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        if exc_type is None:
            self.close()
            return
        try:                           # keep what was written readable; the original error wins
            self.close()
        except BagError as err:
            log.error('%s', err)

    def open(self) -> None:
        """Create the bag directory and storage file."""
        try:
            self._writer = Writer(self.path, version=_BAG_VERSION,
                                  storage_plugin=STORAGES[self.storage])
            self._writer.open()
        except Exception as err:       # noqa: BLE001 - rosbags/OS errors on creation
            self._writer = None
            raise BagError(f"out: cannot create bag '{self.path}': {one_line(err)}") from err

    def close(self) -> None:
        """Finish the bag (index and ``metadata.yaml``); idempotent."""
        writer, self._writer = self._writer, None
        if writer is None:
            return
        try:
            writer.close()
        except Exception as err:       # noqa: BLE001
            with suppress(Exception):
                writer.abort()
            raise BagError(f"out: cannot finish bag '{self.path}': {one_line(err)}") from err

    # -- topics ------------------------------------------------------------------------------

    def add_topic(self, topic: str, msgtype: str) -> None:
        """Register `topic` for messages of the ROS 2 Jazzy type `msgtype`."""
        self._add(topic, msgtype, typestore=TYPESTORE)

    def copy_topic(self, bag: BagReader, topic: str) -> None:
        """Register `topic` with the message definition, hash and QoS it has in `bag`, so that
        its raw messages can be copied with `write_raw`."""
        conn = bag.connection(topic)
        kwargs: dict[str, Any] = {}
        if conn.msgdef.format == MessageDefinitionFormat.MSG and conn.digest:
            kwargs.update(msgdef=conn.msgdef.data, rihs01=conn.digest)
        else:                          # no (or IDL) definition stored: the bag's type store
            kwargs.update(typestore=bag.typestore)
        if isinstance(conn.ext, ConnectionExtRosbag2):
            kwargs.update(serialization_format=conn.ext.serialization_format,
                          offered_qos_profiles=conn.ext.offered_qos_profiles)
        self._add(topic, conn.msgtype, **kwargs)

    def _add(self, topic: str, msgtype: str, **kwargs: Any) -> None:
        if self._writer is None:
            raise BagError(f"out: bag '{self.path}' is not open")
        if topic in self._connections:
            raise BagError(f"topic: '{topic}' is already registered in '{self.path}'")
        try:
            self._connections[topic] = self._writer.add_connection(topic, msgtype, **kwargs)
        except Exception as err:       # noqa: BLE001 - unknown type, bad definition
            raise BagError(f"topic: cannot add '{topic}' ({msgtype}) to '{self.path}': "
                           f'{one_line(err)}') from err
        self.counts[topic] = 0

    # -- messages ----------------------------------------------------------------------------

    def write_raw(self, topic: str, log_time_ns: int, rawdata: bytes | memoryview) -> None:
        """Write an already serialized (CDR) message at log time `log_time_ns`."""
        connection = self._connections.get(topic)
        if connection is None or self._writer is None:
            raise BagError(f"topic: '{topic}' is not registered in open bag '{self.path}'")
        self._writer.write(connection, int(log_time_ns), rawdata)
        self.counts[topic] += 1

    def write_message(self, topic: str, log_time_ns: int, msg: Any) -> None:
        """Serialize a rosbags message of the topic's type and write it."""
        connection = self._connections.get(topic)
        if connection is None:
            raise BagError(f"topic: '{topic}' is not registered in open bag '{self.path}'")
        self.write_raw(topic, log_time_ns, TYPESTORE.serialize_cdr(msg, connection.msgtype))

    def write_odometry(self, topic: str, stamp_ns: int, pose: np.ndarray, *,
                       odom_frame: str = 'odom', base_frame: str = 'base_link',
                       pose_covariance: np.ndarray | None = None,
                       twist: np.ndarray | None = None,
                       twist_covariance: np.ndarray | None = None,
                       log_time_ns: int | None = None) -> None:
        """Write a ``nav_msgs/Odometry`` (register `topic` with `add_topic` first).

        Args:
            stamp_ns: ``header.stamp`` in integer ns (exact).
            pose: ``T_odom_base`` (4x4).
            pose_covariance, twist_covariance: 6x6 (default zeros).
            twist: body velocity ``(vx, vy, vz, wx, wy, wz)`` in `base_frame` (default zeros).
            log_time_ns: bag receive time (default `stamp_ns`).
        """
        msg = odometry_message(TYPESTORE.types, stamp_ns, pose, odom_frame=odom_frame,
                               base_frame=base_frame, pose_covariance=pose_covariance,
                               twist=twist, twist_covariance=twist_covariance)
        self.write_message(topic, stamp_ns if log_time_ns is None else log_time_ns, msg)


class OdometryBagWriter(BagWriter):
    """A new bag of ``nav_msgs/Odometry`` on one topic (plus optional copied topics).

    Args:
        path: the bag directory to create; must not exist (`BagError`, nothing touched).
        storage: ``'mcap'`` or ``'sqlite3'``.
        topic: the odometry topic.
        odom_frame, base_frame: ``header.frame_id`` and ``child_frame_id``.
    """

    def __init__(self, path: str | Path, *, storage: str = 'mcap', topic: str = '/odom',
                 odom_frame: str = 'odom', base_frame: str = 'base_link') -> None:
        super().__init__(path, storage=storage)
        self.topic = topic
        self.odom_frame = odom_frame
        self.base_frame = base_frame

    def open(self) -> None:
        super().open()
        self.add_topic(self.topic, ODOMETRY_TYPE)

    @property
    def count(self) -> int:
        """Odometry messages written so far."""
        return self.counts.get(self.topic, 0)

    def write(self, stamp_ns: int, pose: np.ndarray, pose_covariance: np.ndarray | None = None,
              twist: np.ndarray | None = None, twist_covariance: np.ndarray | None = None, *,
              log_time_ns: int | None = None) -> None:
        """Write one odometry message stamped `stamp_ns` (see `BagWriter.write_odometry`)."""
        self.write_odometry(self.topic, stamp_ns, pose, odom_frame=self.odom_frame,
                            base_frame=self.base_frame, pose_covariance=pose_covariance,
                            twist=twist, twist_covariance=twist_covariance,
                            log_time_ns=log_time_ns)
