"""Test data builders shared by the bag, evaluation and KITTI tests: rosbags messages and tiny
bags written with the rosbags writer directly (independently of planar_vo.io's writer)."""

from __future__ import annotations

import functools
import struct
import zlib
from pathlib import Path
from typing import Any

import numpy as np
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

TS = get_typestore(Stores.ROS2_JAZZY)
T = TS.types
STORAGE_PLUGINS = {'mcap': StoragePlugin.MCAP, 'sqlite3': StoragePlugin.SQLITE3}
ENCODING_LAYOUT = {   # encoding -> (channels, numpy dtype)
    'mono8': (1, np.uint8), '8UC1': (1, np.uint8), 'mono16': (1, np.uint16),
    '16UC1': (1, np.uint16), 'rgb8': (3, np.uint8), 'bgr8': (3, np.uint8),
    'rgba8': (4, np.uint8), 'bgra8': (4, np.uint8),
}


def header(stamp_ns: int, frame_id: str = 'camera') -> Any:
    sec, nanosec = divmod(stamp_ns, 1_000_000_000)
    return T['std_msgs/msg/Header'](stamp=T['builtin_interfaces/msg/Time'](sec=sec,
                                                                           nanosec=nanosec),
                                    frame_id=frame_id)


def image_bytes(pixels: np.ndarray, *, pad: int = 0, bigendian: bool = False
                ) -> tuple[np.ndarray, int]:
    """Row-major bytes of `pixels` (H, W[, C]) with `pad` junk bytes after every row."""
    h = pixels.shape[0]
    dtype = pixels.dtype.newbyteorder('>' if bigendian else '<')
    rows = pixels.astype(dtype).reshape(h, -1).view(np.uint8).reshape(h, -1)
    junk = np.full((h, pad), 0xAB, dtype=np.uint8)
    data = np.hstack([rows, junk]).reshape(-1)
    return data, rows.shape[1] + pad


def image_msg(pixels: np.ndarray, encoding: str, stamp_ns: int = 0, *, pad: int = 0,
              bigendian: bool = False, frame_id: str = 'camera') -> Any:
    data, step = image_bytes(pixels, pad=pad, bigendian=bigendian)
    return T['sensor_msgs/msg/Image'](header=header(stamp_ns, frame_id), height=pixels.shape[0],
                                      width=pixels.shape[1], encoding=encoding,
                                      is_bigendian=int(bigendian), step=step, data=data)


@functools.cache
def zero_png(width: int, height: int) -> bytes:
    """A valid 8-bit grey PNG of `width` x `height` black pixels, built chunk by chunk: zeros
    deflate about 1000:1, so 20000x20000 (400 MB of pixels) takes 389 KB (built in 2 s, once)."""
    def chunk(kind: bytes, data: bytes) -> bytes:
        return (struct.pack('>I', len(data)) + kind + data
                + struct.pack('>I', zlib.crc32(kind + data)))

    deflate = zlib.compressobj(9)
    row = bytes(width + 1)                          # filter byte 0, then the pixels
    idat = b''.join(deflate.compress(row) for _ in range(height)) + deflate.flush()
    header = struct.pack('>IIBBBBB', width, height, 8, 0, 0, 0, 0)   # 8-bit grey, no interlace
    return (b'\x89PNG\r\n\x1a\n' + chunk(b'IHDR', header) + chunk(b'IDAT', idat)
            + chunk(b'IEND', b''))


def compressed_msg(data: bytes, fmt: str, stamp_ns: int = 0) -> Any:
    return T['sensor_msgs/msg/CompressedImage'](header=header(stamp_ns), format=fmt,
                                                data=np.frombuffer(data, dtype=np.uint8))


def camera_info_msg(stamp_ns: int, width: int, height: int, fx: float, *,
                    k: np.ndarray | None = None) -> Any:
    K = np.array([[fx, 0, width / 2], [0, fx, height / 2], [0, 0, 1]]) if k is None else k
    return T['sensor_msgs/msg/CameraInfo'](
        header=header(stamp_ns), height=height, width=width, distortion_model='plumb_bob',
        d=np.zeros(5), k=np.asarray(K, float).reshape(9), r=np.eye(3).reshape(9),
        p=np.hstack([K, np.zeros((3, 1))]).reshape(12), binning_x=0, binning_y=0,
        roi=T['sensor_msgs/msg/RegionOfInterest'](x_offset=0, y_offset=0, height=0, width=0,
                                                  do_rectify=False))


def odometry_msg(stamp_ns: int, x: float, y: float = 0.0, yaw: float = 0.0) -> Any:
    geo = 'geometry_msgs/msg/'
    pose = T[geo + 'Pose'](position=T[geo + 'Point'](x=x, y=y, z=0.0),
                           orientation=T[geo + 'Quaternion'](x=0.0, y=0.0, z=np.sin(yaw / 2),
                                                             w=np.cos(yaw / 2)))
    twist = T[geo + 'Twist'](linear=T[geo + 'Vector3'](x=3.0, y=4.0, z=0.0),
                             angular=T[geo + 'Vector3'](x=0.0, y=0.0, z=0.0))
    return T['nav_msgs/msg/Odometry'](
        header=header(stamp_ns, 'odom'), child_frame_id='base_link',
        pose=T[geo + 'PoseWithCovariance'](pose=pose, covariance=np.zeros(36)),
        twist=T[geo + 'TwistWithCovariance'](twist=twist, covariance=np.zeros(36)))


def twist_msg(stamp_ns: int, vx: float) -> Any:
    geo = 'geometry_msgs/msg/'
    return T[geo + 'TwistStamped'](
        header=header(stamp_ns, 'base_link'),
        twist=T[geo + 'Twist'](linear=T[geo + 'Vector3'](x=vx, y=0.0, z=0.0),
                               angular=T[geo + 'Vector3'](x=0.0, y=0.0, z=0.0)))


def write_bag(path: Path, storage: str, entries: list[tuple[str, str, int, Any]]) -> Path:
    """A bag with `entries` ``(topic, msgtype, log_time_ns, message)`` in that order (a
    message None: the topic only, without a message)."""
    with Writer(path, version=9, storage_plugin=STORAGE_PLUGINS[storage]) as writer:
        connections = {}
        for topic, msgtype, log_ns, msg in entries:
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, msgtype, typestore=TS)
            if msg is not None:
                writer.write(connections[topic], log_ns, TS.serialize_cdr(msg, msgtype))
    return path


def storage_file(bag: Path) -> Path:
    """The single .mcap/.db3 file of a bag directory."""
    (file,) = [p for p in bag.iterdir() if p.suffix in ('.mcap', '.db3')]
    return file


def corrupt_mid_way(bag: Path, marker: bytes) -> None:
    """Damage a bag so that opening works and reading fails part-way through.

    sqlite3: the page holding `marker` (bytes of a message in the middle) gets a broken header;
    MCAP: the second chunk gets a wrong CRC. Both are detected only when that part is read.
    """
    file = storage_file(bag)
    data = bytearray(file.read_bytes())
    if file.suffix == '.db3':
        offset = data.find(marker)
        assert offset > 0
        page = offset // 4096 * 4096
        data[page:page + 4] = b'\xff\xff\xff\xff'
    else:
        chunks, pos = [], 8
        while pos < len(data) - 8 and len(chunks) < 2:
            opcode, length = data[pos], int.from_bytes(data[pos + 1:pos + 9], 'little')
            if opcode == 0x06:
                chunks.append(pos)
            pos += 9 + length
        assert len(chunks) == 2, 'the bag needs more than 1 MiB of messages'
        crc = chunks[1] + 9 + 24          # opcode, length, start/end time, uncompressed size
        data[crc:crc + 4] = b'\x01\x02\x03\x04'
    file.write_bytes(bytes(data))
