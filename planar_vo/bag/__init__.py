"""ROS 2 bags (sqlite3 and MCAP) through rosbags: reading, writing, replay, KITTI import.

The only subpackage that imports rosbags. Reading: `open_bag`, `iter_camera_frames`,
`iter_messages`; writing: `OdometryBagWriter` (and the general `BagWriter`); offline replay of a
frame processor: `replay_bag`; dataset conversion: `import_kitti`. Every failure is a one-line
`planar_vo.errors.BagError` (or `InputError` for a malformed KITTI folder).
"""

from __future__ import annotations

from planar_vo.bag.images import CameraFrame, iter_camera_frames
from planar_vo.bag.kitti import import_kitti
from planar_vo.bag.reader import BagReader, StampedMessage, iter_messages, open_bag
from planar_vo.bag.replay import FrameProcessor, ReplaySummary, replay_bag
from planar_vo.bag.writer import BagWriter, OdometryBagWriter

__all__ = [
    'BagReader',
    'BagWriter',
    'CameraFrame',
    'FrameProcessor',
    'OdometryBagWriter',
    'ReplaySummary',
    'StampedMessage',
    'import_kitti',
    'iter_camera_frames',
    'iter_messages',
    'open_bag',
    'replay_bag',
]
