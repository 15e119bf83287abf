"""Writing ROS 2 bags (MCAP or sqlite3) with rosbags: odometry, any Jazzy message, raw copies.

Writers never overwrite: an existing output path is refused before anything is touched. A bag is
written into a hidden folder next to its path and renamed onto the path only once it is
complete, so the path either holds a complete, readable bag or does not exist:

- an exception inside the ``with`` block (bad input found mid-way, an interruption) still
  finishes the bag (index and ``metadata.yaml``): everything written up to it is kept;
- a bag that cannot be finished, or whose storage failed to write a message (a full disk), is
  removed: a half-written bag is never left behind nor reported as kept;
- a bag the caller `BagWriter.discard` s (bad input found mid-way where the part written would
  pass for the whole, as in an import) is removed too.

Either way the exception leaving the ``with`` block carries a note saying what was kept
(`BagWriter.outcome`). Writing a message and finishing the bag are never cut by SIGINT/SIGTERM
(`planar_vo.io.outputs.deferred_interrupts`).
"""

from __future__ import annotations

import logging
import shutil
import sqlite3
import tempfile
import zlib
from collections.abc import Callable
from contextlib import suppress
from pathlib import Path
from types import TracebackType
from typing import Any

import numpy as np
from rosbags.interfaces import ConnectionExtRosbag2, MessageDefinitionFormat
from rosbags.rosbag2 import StoragePlugin, Writer

from planar_vo.errors import BagError
from planar_vo.io.outputs import deferred_interrupts
from planar_vo.io.reader import TYPESTORE, BagReader, one_line
from planar_vo.ros.messages import odometry_message

__all__ = ['MAX_STAMP_NS', 'ODOMETRY_TYPE', 'STORAGES', 'BagWriter', 'OdometryBagWriter',
           'check_stamp_ns', 'stamp_chunk_crcs']

log = logging.getLogger(__name__)

ODOMETRY_TYPE = 'nav_msgs/msg/Odometry'
STORAGES = {'mcap': StoragePlugin.MCAP, 'sqlite3': StoragePlugin.SQLITE3}
# MCAP records (the format's specification): the file's magic, and the opcodes of a chunk and of
# the end of the data section.
_MCAP_MAGIC = b'\x89MCAP0\r\n'
_MCAP_CHUNK, _MCAP_DATA_END = 0x06, 0x0F
_BAG_VERSION = 9                       # rosbag2 metadata version written by Jazzy
# builtin_interfaces/Time holds int32 seconds: stamps from 0 to 2038-01-19 03:14:07.999999999.
MAX_STAMP_NS = 2**31 * 1_000_000_000 - 1
# What a storage raises when the disk is full or the file cannot be written.
_STORAGE_ERRORS = (OSError, sqlite3.Error)


def _reason(err: BaseException) -> str:
    """An OS error's reason (``No space left on device``), else the error on one line."""
    return getattr(err, 'strerror', None) or one_line(err)


def check_stamp_ns(role: str, stamp_ns: int) -> int:
    """`stamp_ns` as an int if a ``builtin_interfaces/Time`` (and a bag) can hold it, i.e.
    ``0 <= stamp_ns <= MAX_STAMP_NS``; else `BagError` naming `role` and the value."""
    if not 0 <= stamp_ns <= MAX_STAMP_NS:
        raise BagError(f'{role}: {stamp_ns} ns is outside the range of a ROS time stamp '
                       f'(0 to {MAX_STAMP_NS} ns, i.e. 1970 to 2038)')
    return int(stamp_ns)


def stamp_chunk_crcs(path: Path) -> int:
    """Write the CRC-32 of each uncompressed chunk's records into an MCAP file's chunk
    headers (``uncompressed_crc``; 0 means none, which rosbags' writer leaves): readers then
    detect damaged chunk data (a user test: 64 KiB overwritten inside a bag replayed without a
    word, the poses 9 cm off). Streams the file a chunk at a time (rosbags writes about 1 MiB
    each); a compressed chunk, or one with a CRC already, is left as it is. Returns the chunks
    stamped."""
    stamped = 0
    with open(path, 'r+b') as f:
        if f.read(len(_MCAP_MAGIC)) != _MCAP_MAGIC:
            raise BagError(f"'{path}' is not an MCAP file")
        while len(head := f.read(9)) == 9:
            op, length, start = head[0], int.from_bytes(head[1:], 'little'), f.tell()
            if op == _MCAP_DATA_END:
                break
            if op == _MCAP_CHUNK:
                # start time, end time, uncompressed size (u64 each), uncompressed CRC (u32),
                # compression (a u32-length string), records (a u64-length byte string)
                crc = int.from_bytes(f.read(28)[24:], 'little')
                compression = f.read(int.from_bytes(f.read(4), 'little'))
                records = f.read(int.from_bytes(f.read(8), 'little'))
                if not compression and not crc:
                    f.seek(start + 24)
                    f.write(zlib.crc32(records).to_bytes(4, 'little'))
                    stamped += 1
            f.seek(start + length)
    return stamped


class BagWriter:
    """A new ROS 2 bag (context manager): typed messages, odometry and raw copies.

    Args:
        path: the bag directory to create; must not exist.
        storage: ``'mcap'`` or ``'sqlite3'``.

    Attributes:
        kept: True once the complete bag is at `path`.
        counts: messages written per topic.

    Raises:
        BagError: `path` exists (nothing is touched) or `storage` is unknown.
    """

    def __init__(self, path: str | Path, *, storage: str = 'mcap') -> None:
        if not str(path).strip():
            raise BagError('out: an empty path; expected the folder to write the bag to')
        self.path = Path(path)
        if storage not in STORAGES:
            raise BagError(f"storage: expected one of {list(STORAGES)}, got '{storage}'")
        self._refuse_existing()
        if self.path.suffix.lower() in ('.mcap', '.db3'):
            # A ROS 2 bag is a folder (metadata.yaml and the storage file): 'x.mcap' would
            # become the folder x.mcap holding x.mcap.mcap.
            raise BagError(f"out: '{path}' names a storage file; a bag is written as a folder "
                           f"(metadata.yaml and the {storage} file): give the folder's name, "
                           f"e.g. '{self.path.with_suffix('')}'")
        self.storage = storage
        self.counts: dict[str, int] = {}
        # Written to metadata.yaml's custom_data when the bag is finished (`close`).
        self.custom_data: dict[str, str] = {}
        # Called with the exception that ends a ``with`` block early, before the bag is
        # finished (e.g. to mark it partial in `custom_data`).
        self.on_stop: Callable[[BaseException], None] | None = None
        self.kept = False
        self._writer: Writer | None = None
        self._tmp: Path | None = None
        self._failure: str | None = None
        self._connections: dict[str, Any] = {}

    def _refuse_existing(self) -> None:
        if self.path.exists() or self.path.is_symlink():
            raise BagError(f"out: '{self.path}' already exists; refusing to overwrite it "
                           f'(remove it or choose another path)')

    # -- context -----------------------------------------------------------------------------

    def __enter__(self) -> BagWriter:
        self.open()
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        if exc is None:
            self.close()
            return
        # One block that a (second) stop signal cannot cut short before the bag is finished
        # (a review: `on_stop` ran unprotected); it is raised after, with the note added too
        # (a review: the note was lost on the original exception).
        try:
            with deferred_interrupts():
                if self.on_stop is not None:
                    try:
                        self.on_stop(exc)
                    except Exception:  # noqa: BLE001 - a mark is not worth the bag
                        log.debug('on_stop failed', exc_info=True)
                try:                   # keep what was written readable; the original error wins
                    self.close()
                except BagError as err:
                    log.debug('%s', err)   # the note below says it
                exc.add_note(self.outcome)
        except KeyboardInterrupt as late:
            late.add_note(self.outcome)
            raise

    @property
    def outcome(self) -> str:
        """What is at `path`: a complete bag and its message counts, or nothing and why."""
        if self.kept:
            counts = ', '.join(f'{t}: {n}' for t, n in self.counts.items()) or 'none'
            return f"kept '{self.path}', a complete bag with messages {counts}"
        if self._failure:
            return f"nothing was kept at '{self.path}' ({self._failure})"
        return f"nothing was written to '{self.path}'"

    def open(self) -> None:
        """Create the storage in a hidden folder next to `path`."""
        with deferred_interrupts():
            self._open()

    def _open(self) -> None:
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._tmp = Path(tempfile.mkdtemp(prefix=f'.{self.path.name}.', suffix='.partial',
                                              dir=self.path.parent))
            self._writer = Writer(self._tmp / self.path.name, version=_BAG_VERSION,
                                  storage_plugin=STORAGES[self.storage])
            self._writer.open()
        except Exception as err:       # noqa: BLE001 - rosbags/OS errors on creation
            self._writer = None
            self._remove_tmp()
            raise BagError(f"out: cannot create bag '{self.path}': {one_line(err)}") from err

    def close(self) -> None:
        """Finish the bag (index and ``metadata.yaml``) and move it to `path`; idempotent.

        Raises:
            BagError: the bag cannot be finished (a full disk) or a message could not be
                written before; the partial bag is removed and nothing is kept.
        """
        writer, self._writer = self._writer, None
        if writer is None:
            return
        with deferred_interrupts():
            try:
                if self._failure:
                    raise BagError(self._failure)
                for key, value in self.custom_data.items():
                    writer.set_custom_data(key, value)
                writer.close()
                for mcap in (self._tmp / self.path.name).glob('*.mcap'):
                    stamp_chunk_crcs(mcap)
                self._refuse_existing()
                (self._tmp / self.path.name).rename(self.path)
            except Exception as err:   # noqa: BLE001 - storage, OS and rosbags errors
                with suppress(Exception):
                    writer.abort()
                self._failure = self._failure or f'cannot finish the bag: {_reason(err)}'
                raise BagError(f"out: {self.outcome}") from err
            finally:
                self._remove_tmp()
            self.kept = True           # inside the block: a deferred stop signal comes after

    def discard(self, reason: str) -> None:
        """Remove the bag instead of finishing it: nothing is kept at `path`, and `outcome`
        says `reason`. A no-op once the bag is closed."""
        writer, self._writer = self._writer, None
        if writer is None:
            return
        with deferred_interrupts():
            with suppress(Exception):
                writer.abort()
            self._remove_tmp()
            self._failure = reason

    def _remove_tmp(self) -> None:
        tmp, self._tmp = self._tmp, None
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)

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
        """Write an already serialized (CDR) message at log time `log_time_ns`.

        Raises:
            BagError: unknown topic, a log time outside `check_stamp_ns`'s range, or the
                storage failed (a full disk): the bag is then lost (see `close`).
        """
        connection = self._connections.get(topic)
        if connection is None or self._writer is None:
            raise BagError(f"topic: '{topic}' is not registered in open bag '{self.path}'")
        if self._failure:
            raise BagError(f"out: bag '{self.path}' takes no more messages after a failed "
                           f'write')
        log_time_ns = check_stamp_ns(f"log time on '{topic}'", log_time_ns)
        with deferred_interrupts():
            try:
                self._writer.write(connection, log_time_ns, rawdata)
            except _STORAGE_ERRORS as err:
                self._failure = 'removed after a failed write'
                raise BagError(f"out: cannot write to bag '{self.path}' ({_reason(err)})"
                               ) from err
            # Counted inside the block: a stop signal deferred to its end must not leave a
            # written message uncounted.
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
        stamp_ns = check_stamp_ns(f"stamp on '{topic}'", stamp_ns)
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
