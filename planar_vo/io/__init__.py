"""ROS 2 bags (sqlite3 and MCAP) through rosbags, the only subpackage that imports rosbags.

Reading: `open_bag`, `iter_camera_frames`, `iter_messages`; writing: `OdometryBagWriter` (and the
general `BagWriter`), `CameraBagWriter` (camera drives); conversion: `import_kitti` (a KITTI
sequence folder), `import_video` (a video file or a folder of images).
Every failure is a one-line `planar_vo.errors.BagError` (or `InputError` for a malformed source
to convert).
"""

from __future__ import annotations

from planar_vo.io.camera_bag import CameraBagWriter
from planar_vo.io.images import CameraFrame, iter_camera_frames
from planar_vo.io.kitti import import_kitti
from planar_vo.io.reader import BagReader, StampedMessage, iter_messages, open_bag
from planar_vo.io.video import import_video
from planar_vo.io.writer import BagWriter, OdometryBagWriter

__all__ = [
    'BagReader',
    'BagWriter',
    'CameraBagWriter',
    'CameraFrame',
    'OdometryBagWriter',
    'StampedMessage',
    'import_kitti',
    'import_video',
    'iter_camera_frames',
    'iter_messages',
    'open_bag',
]
