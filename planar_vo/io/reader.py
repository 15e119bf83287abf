"""Reading ROS 2 bags (sqlite3 and MCAP) with rosbags, with one-line `BagError` on bad input.

`open_bag` accepts a bag directory (with ``metadata.yaml``) or a single ``.mcap``/``.db3`` file.
Bags without embedded message definitions are decoded with the ROS 2 Jazzy type store.
"""

from __future__ import annotations

import logging
from collections import Counter
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

from rosbags.highlevel import AnyReader
from rosbags.interfaces import Connection
from rosbags.rosbag2 import Reader as Rosbag2Reader
from rosbags.typesys import Stores, get_typestore

from planar_vo.errors import BagError, one_line
from planar_vo.ros.messages import stamp_to_ns

__all__ = [
    'BagMessage',
    'BagReader',
    'StampedMessage',
    'iter_messages',
    'open_bag',
]

log = logging.getLogger(__name__)

TYPESTORE = get_typestore(Stores.ROS2_JAZZY)
BAG_SUFFIXES = ('.mcap', '.db3')


class BagMessage(NamedTuple):
    """One serialized message as stored: ``log_time_ns`` is the bag's receive time."""

    topic: str
    msgtype: str
    log_time_ns: int
    rawdata: bytes
    connection: Connection


@dataclass(frozen=True)
class StampedMessage:
    """A decoded message with its bag log time and header stamp (log time if it has none)."""

    log_time_ns: int
    stamp_ns: int
    msg: Any

    @property
    def stamp(self) -> float:
        """Header stamp in seconds."""
        return self.stamp_ns / 1_000_000_000     # int / int: correctly rounded


class BagReader:
    """An open bag (made by `open_bag`): topics, filtered message streams, decoding."""

    def __init__(self, path: Path, reader: AnyReader) -> None:
        self.path = path
        self._reader = reader
        # Messages of a topic that its index counts but a full read of it did not yield
        # (`messages`): damaged storage the reader skipped without an error.
        self.unread: dict[str, int] = {}

    @property
    def typestore(self) -> Any:
        """The rosbags type store holding this bag's message definitions."""
        return self._reader.typestore

    @property
    def topics(self) -> dict[str, str]:
        """Topic name -> message type (``'sensor_msgs/msg/Image'``), sorted by name."""
        return {c.topic: c.msgtype for c in sorted(self._reader.connections,
                                                   key=lambda c: c.topic)}

    def describe_topics(self, counts: bool = False) -> str:
        """``'/a (pkg/msg/A), /b (pkg/msg/B)'`` for error messages; with `counts`, each with
        its number of messages: ``'/a (pkg/msg/A): 12'``."""
        return ', '.join(f'{t} ({m})' + (f': {self.count(t)}' if counts else '')
                         for t, m in self.topics.items()) or 'none'

    def count(self, topic: str) -> int:
        """Number of messages on `topic` recorded in the bag's index."""
        return sum(c.msgcount for c in self._reader.connections if c.topic == topic)

    def connection(self, topic: str) -> Connection:
        """The (first) connection of `topic`."""
        for c in self._reader.connections:
            if c.topic == topic:
                return c
        raise self._unknown_topic('topic', topic)

    def topics_of_type(self, *msgtypes: str) -> list[str]:
        """Topics whose type is one of `msgtypes`, sorted by name."""
        return [t for t, m in self.topics.items() if m in msgtypes]

    def require_topic(self, role: str, topic: str, msgtypes: Iterable[str] = ()) -> str:
        """Check that `topic` exists (and has one of `msgtypes`); `role` names the argument."""
        topics = self.topics
        if topic not in topics:
            raise self._unknown_topic(role, topic)
        msgtypes = tuple(msgtypes)
        if msgtypes and topics[topic] not in msgtypes:
            raise BagError(f"{role}: '{topic}' in '{self.path}' has type {topics[topic]}, "
                           f"expected {' or '.join(msgtypes)}")
        return topic

    def find_topic(self, role: str, topic: str | None, msgtypes: Iterable[str], *,
                   required: bool = True, near: str | None = None) -> str | None:
        """`topic` checked, or the only topic of one of `msgtypes` when `topic` is None.

        With several candidates, the one in the namespace of `near` (e.g. the camera info next to
        the image topic) is chosen if there is exactly one; otherwise `BagError` lists them.
        Without candidates: `BagError` if `required`, else None.
        """
        msgtypes = tuple(msgtypes)
        if topic is not None:
            return self.require_topic(role, topic, msgtypes)
        found = self.topics_of_type(*msgtypes)
        if len(found) > 1 and near is not None:
            namespace = near.rsplit('/', 1)[0] + '/'
            close = [t for t in found if t.startswith(namespace)]
            found = close if len(close) == 1 else found
        if len(found) == 1:
            return found[0]
        if not found:
            if not required:
                return None
            raise BagError(f"{role}: no {' or '.join(msgtypes)} topic in '{self.path}'; "
                           f'topics: {self.describe_topics()}')
        raise BagError(f"{role}: '{self.path}' has several candidate topics "
                       f"({', '.join(found)}); choose one")

    def messages(self, topics: Iterable[str]) -> Iterator[BagMessage]:
        """Serialized messages of `topics` in log-time order.

        When the stream ends, each topic that yielded fewer messages than the bag's index
        counts has the difference in `unread` (a damaged MCAP chunk is skipped by the reader
        without an error: a user test lost an image that way, unsaid).

        Raises:
            BagError: the storage fails while reading (a corrupt or truncated file discovered
                mid-way); messages yielded before stay valid.
        """
        wanted = set(topics)
        connections = [c for c in self._reader.connections if c.topic in wanted]
        if not connections:                 # rosbags reads *every* topic for an empty filter
            return
        stream = self._reader.messages(connections=connections)
        count = 0
        read: Counter[str] = Counter()
        while True:
            try:
                connection, log_time, rawdata = next(stream)
            except StopIteration:
                for topic in wanted & set(self.topics):
                    missing = self.count(topic) - read[topic]
                    if missing > 0:
                        self.unread[topic] = missing
                    else:
                        self.unread.pop(topic, None)
                return
            except Exception as err:   # noqa: BLE001 - any storage failure means a damaged file
                raise BagError(f"bag '{self.path}': corrupt or truncated, reading failed after "
                               f'{count} messages ({type(err).__name__}: {one_line(err)})'
                               ) from err
            count += 1
            read[connection.topic] += 1
            yield BagMessage(connection.topic, connection.msgtype, log_time, rawdata, connection)

    def deserialize(self, message: BagMessage) -> Any:
        """Decode a `BagMessage`; `BagError` naming the topic and log time if that fails."""
        try:
            return self._reader.deserialize(message.rawdata, message.msgtype)
        except Exception as err:       # noqa: BLE001 - rosbags raises several types on bad CDR
            raise BagError(f"bag '{self.path}': cannot decode {message.msgtype} on "
                           f"'{message.topic}' at log time {message.log_time_ns} ns "
                           f'({one_line(err)})') from err

    def _unknown_topic(self, role: str, topic: str) -> BagError:
        return BagError(f"{role}: '{topic}' is not a topic of '{self.path}'; available topics: "
                        f'{self.describe_topics()}')


@contextmanager
def open_bag(path: str | Path) -> Iterator[BagReader]:
    """Open a ROS 2 bag for reading (context manager yielding a `BagReader`).

    Args:
        path: a bag directory (``metadata.yaml`` + storage files, sqlite3 or MCAP) or a single
            ``.mcap`` / ``.db3`` file.

    Raises:
        BagError: missing path, not a bag, or a corrupt/truncated file (one line).
    """
    path = Path(path)
    if not path.exists():
        raise BagError(f"bag: '{path}' does not exist")
    if path.is_dir() and not (path / 'metadata.yaml').is_file():
        raise BagError(f"bag: '{path}' is not a bag: expected a directory with metadata.yaml or a "
                       f"{'/'.join(BAG_SUFFIXES)} file")
    if path.is_file() and path.suffix not in BAG_SUFFIXES:
        raise BagError(f"bag: '{path}' is not a bag: expected a rosbag2 directory or a "
                       f"{'/'.join(BAG_SUFFIXES)} file, got a '{path.suffix}' file")
    try:
        reader = AnyReader([path], default_typestore=TYPESTORE)
        if path.is_dir() and not reader.is2:
            # rosbags takes every path ending in '.bag' for a ROS 1 bag file; a rosbag2
            # directory may be named so (``import-kitti seq --out drive.bag``: replay refused it).
            reader.is2, reader.readers = True, [Rosbag2Reader(path)]
        reader.open()
    except Exception as err:           # noqa: BLE001 - rosbags raises many types on damaged files
        raise BagError(f"bag: cannot open '{path}': corrupt, truncated or not a ROS 2 bag "
                       f'({type(err).__name__}: {one_line(err)})') from err
    try:
        yield BagReader(path, reader)
    finally:
        reader.close()


def iter_messages(bag: BagReader, topic: str, msgtypes: Iterable[str] = (), *,
                  role: str = 'topic') -> Iterator[StampedMessage]:
    """Decoded messages of one topic (e.g. speed or ground truth) in log-time order.

    The stamp is ``msg.header.stamp`` when the message has a header, else the log time.
    `role` names the topic argument in error messages (e.g. ``'speed_topic'``).

    Raises:
        BagError: unknown topic or wrong type (listing what the bag has), undecodable message,
            or a storage failure.
    """
    bag.require_topic(role, topic, msgtypes)
    for message in bag.messages([topic]):
        msg = bag.deserialize(message)
        header = getattr(msg, 'header', None)
        stamp = stamp_to_ns(header.stamp) if header is not None else message.log_time_ns
        yield StampedMessage(message.log_time_ns, stamp, msg)
