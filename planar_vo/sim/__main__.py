"""Render a sample drive and report the time per frame: ``python -m planar_vo.sim --help``.

Times are CPU seconds of this process (``time.process_time``), so other load on the machine
does not inflate them; OpenCV is limited to one thread.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import cv2
import numpy as np

from planar_vo.cli import CommandParser
from planar_vo.core.camera import CameraModel
from planar_vo.core.conventions import mount_transform
from planar_vo.sim import StreetWorld, render, s_curve, stop_and_go, straight, turn

CAMERAS = {
    'vga': CameraModel.pinhole(640, 480, 500.0),
    'kitti': CameraModel.pinhole(1241, 376, 718.856, cx=607.19, cy=185.22),
    'vga-fisheye': CameraModel(640, 480, np.array([[330.0, 0, 319.5], [0, 330.0, 239.5],
                                                   [0, 0, 1]]), 'equidistant',
                               (0.05, -0.01, 0.002, -0.0005)),
}


def main(argv: list[str] | None = None) -> int:
    parser = CommandParser(
        prog='python -m planar_vo.sim', description=__doc__,
        epilog='example: python -m planar_vo.sim --camera kitti --frames 40 --save /tmp/drive')
    parser.add_argument('--camera', choices=sorted(CAMERAS), default='vga')
    parser.add_argument('--frames', type=int, default=30, help='frames rendered (evenly spaced)')
    parser.add_argument('--seed', type=int, default=0)
    parser.add_argument('--save', type=Path, help='write the frames as PNG into this folder')
    args = parser.parse_args(argv)
    cv2.setNumThreads(1)
    drive = straight(40.0).then(turn(np.pi / 2, radius=20.0), stop_and_go(),
                                turn(-np.pi / 2, radius=15.0), s_curve())
    t0 = time.process_time()
    world = StreetWorld.along(drive, seed=args.seed)
    t_world = time.process_time() - t0
    poses = drive.camera_poses(mount_transform(height=1.5))
    camera = CAMERAS[args.camera]
    render(world, camera, poses[0])                      # builds textures and ray caches
    if args.save:
        args.save.mkdir(parents=True, exist_ok=True)
    times = []
    for k in np.linspace(0, len(poses) - 1, max(1, args.frames)).astype(int):
        t0 = time.process_time()
        frame = render(world, camera, poses[k])
        times.append(time.process_time() - t0)
        if args.save:
            cv2.imwrite(str(args.save / f'frame_{k:04d}.png'), frame.image)
    ms = np.array(times) * 1e3
    print(f'{args.camera} {camera.width}x{camera.height}: {len(ms)} frames, render median '
          f'{np.median(ms):.1f} ms, max {ms.max():.1f} ms (CPU time); world of {len(world)} '
          f'planes built in {t_world * 1e3:.0f} ms')
    return 0


if __name__ == '__main__':
    sys.exit(main())
