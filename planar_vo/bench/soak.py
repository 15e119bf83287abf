"""``planar_vo bench soak``: memory and time per frame over a long drive through the node.

A closed lap of the rendered street world (two straights and two 180-degree turns at 8 m/s,
10 Hz) is rendered once and driven round and round, with stamps going on at 10 Hz, through the
node's own code path: a `planar_vo.ros.node.PlanarVoNode` in this process (its own rclpy context,
no DDS peers but a subscriber on ``path``, so that the path is built and published as for
rviz), its CameraInfo and image callbacks called with rclpy messages, so the pipeline, the
odometry, path, status and diagnostics messages all run as in ``ros2 run``.

Every ``--every`` frames it records the process's resident memory (RSS), the median CPU time
and wall time of the node per frame, and the path's share. Target: memory and time flat within
5 % after the first block (which includes the start-up allocations and the path filling up to
``ros.path_max_length``): the change over the drive of a robust straight-line fit (Theil-Sen)
through the blocks. The CPU time of the node's thread is the measure of its work; the wall time
also carries the other processes of a shared machine.
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import numpy as np

HELP = 'memory and time per frame over a long drive through the node (flat within 5 percent)'
EXAMPLES = """examples:
  planar_vo bench soak --frames 10000 --out planar_vo/bench/results/soak
  planar_vo bench soak --frames 2000 --every 250
"""
RATE = 10.0
SPEED = 8.0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``planar_vo bench soak`` (``--out`` is added by the bench command)."""
    parser.epilog = EXAMPLES
    parser.add_argument('--frames', type=int, default=10000,
                        help='frames driven (default: 10000, 17 minutes at 10 Hz)')
    parser.add_argument('--every', type=int, default=500,
                        help='frames per measurement block (default: 500)')
    parser.add_argument('--camera', choices=('640x480', '1241x376'), default='640x480',
                        help='rendered camera (default: 640x480)')


def lap():
    """A closed lap (m, s): 40 m straight, a 180-degree left turn of radius 15 m, 40 m back, a
    second turn; its last pose is one frame short of the first, so laps chain seamlessly."""
    from planar_vo.sim import straight, turn

    leg = straight(40.0, speed=SPEED, rate=RATE)
    bend = turn(math.pi, radius=15.0, speed=SPEED, rate=RATE)
    closed = leg.then(bend, leg, bend)              # ends where it starts
    return closed.subset(slice(0, len(closed) - 1))


def run(args: argparse.Namespace) -> int:
    from planar_vo.bench.common import require, write_markdown
    from planar_vo.errors import InputError

    if args.frames < 2 * args.every or args.every < 10:
        raise InputError(f'--frames, --every: expected --every >= 10 and --frames >= 2 * '
                         f'--every, got {args.frames}, {args.every}')
    require('rclpy')
    blocks, info = soak(args.frames, args.every, args.camera)
    section = report(blocks, info)
    print(section + '\n', flush=True)
    path = Path(args.out) / 'soak.md'
    write_markdown(path, 'planar_vo bench soak', args.command, [section])
    print(f'wrote {path}')
    return 0


def trend_change(x: np.ndarray, y: np.ndarray) -> float:
    """Percent change of ``y`` from ``x[0]`` to ``x[-1]`` along its Theil-Sen line (the median
    of the pairwise slopes: a few blocks slowed by other processes do not tilt it)."""
    i, j = np.triu_indices(len(x), 1)
    slope = float(np.median((y[j] - y[i]) / (x[j] - x[i])))
    level = float(np.median(y - slope * x))
    start = level + slope * x[0]
    return 100.0 * slope * (x[-1] - x[0]) / start


def _rss_mb() -> float:
    """Resident memory of this process (MB), from /proc (Linux) or the peak from getrusage."""
    try:
        for line in Path('/proc/self/status').read_text().splitlines():
            if line.startswith('VmRSS:'):
                return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def soak(frames: int, every: int, camera_name: str) -> tuple[list[dict], dict]:
    """Drive ``frames`` frames through an in-process node; one dict per block of ``every``."""
    import rclpy
    from nav_msgs.msg import Path as PathMsg
    from rclpy.context import Context
    from rclpy.parameter import Parameter
    from rclpy.signals import SignalHandlerOptions
    from sensor_msgs.msg import CameraInfo, Image

    from planar_vo.core.conventions import mount_transform
    from planar_vo.pipeline.threads import limit_blas_threads
    from planar_vo.ros.node import PlanarVoNode
    from planar_vo.sim import StreetWorld
    from planar_vo.sim.drive import render_drive
    from planar_vo.tools.demo import CAMERAS

    limit_blas_threads()
    camera = CAMERAS[camera_name]()
    trajectory = lap()
    world = StreetWorld.along(trajectory, seed=0)
    start = time.perf_counter()
    images = [f.image for f in render_drive(trajectory, world, camera,
                                            mount_transform(height=1.5))]
    render_time = time.perf_counter() - start

    context = Context()
    rclpy.init(context=context, signal_handler_options=SignalHandlerOptions.NO)
    try:
        node = PlanarVoNode(context=context, parameter_overrides=[
            Parameter('mount.height', value=1.5), Parameter('ros.publish_tf', value=False)])
        listener = rclpy.create_node('soak_path_listener', context=context)
        listener.create_subscription(PathMsg, 'path', lambda msg: None, 1)
        deadline = time.monotonic() + 10.0
        while node._path_pub.get_subscription_count() == 0 and time.monotonic() < deadline:
            time.sleep(0.01)
        subscribed = node._path_pub.get_subscription_count() > 0
        times: dict[str, list[float]] = {'time_ms.node': [], 'time_ms.path': []}
        publish = node._status_pub.publish

        def keep_times(array) -> None:             # the status the node publishes, read back
            values = {kv.key: kv.value for kv in array.status[0].values}
            for key, column in times.items():
                column.append(float(values[key]))
            publish(array)

        node._status_pub.publish = keep_times
        info = CameraInfo(width=camera.width, height=camera.height, distortion_model='',
                          k=camera.K.ravel().tolist())
        node._on_camera_info(info)
        message = Image(height=camera.height, width=camera.width, encoding='mono8',
                        is_bigendian=0, step=camera.width)
        message.header.frame_id = 'camera'
        payloads = [image.tobytes() for image in images]
        blocks: list[dict] = []
        t0 = 1_700_000_000 * 10 ** 9
        cpu = []
        for i in range(frames):
            stamp = t0 + round(i * 1e9 / RATE)
            message.header.stamp.sec, message.header.stamp.nanosec = divmod(stamp, 10 ** 9)
            message.data = payloads[i % len(payloads)]
            before = time.thread_time()
            node._on_image(message)
            cpu.append(1e3 * (time.thread_time() - before))
            if (i + 1) % every == 0:
                node._on_diagnostics_timer()
                block = slice(i + 1 - every, i + 1)
                blocks.append({
                    'frames': i + 1,
                    'rss_mb': _rss_mb(),
                    'cpu_ms': float(np.median(cpu[block])),
                    'node_ms': float(np.median(times['time_ms.node'][block])),
                    'path_ms': float(np.mean(times['time_ms.path'][block])),
                    'path_max_ms': float(np.max(times['time_ms.path'][block])),
                    'path_poses': len(node.path_poses()),
                    'odometry_out': node.odometry_out,     # the origin's too
                })
                print(f'soak: {blocks[-1]}', flush=True)
        summary = node.summary()
        node.destroy_node()
        listener.destroy_node()
    finally:
        context.try_shutdown()
    return blocks, {'camera': camera_name, 'lap_frames': len(images), 'render_s': render_time,
                    'summary': summary, 'path_subscribed': subscribed, 'every': every}


def report(blocks: list[dict], info: dict) -> str:
    """The markdown section: one row per block and the flatness verdict."""
    from planar_vo.bench.common import markdown_table

    rows = [(b['frames'], f'{b["frames"] / RATE / 60:.1f}', f'{b["rss_mb"]:.1f}',
             f'{b["cpu_ms"]:.2f}', f'{b["node_ms"]:.2f}', f'{b["path_ms"]:.3f}',
             f'{b["path_max_ms"]:.2f}', b['path_poses'], b['odometry_out']) for b in blocks]
    table = markdown_table(['frames', 'drive (min)', 'RSS (MB)', 'node CPU (ms/frame)',
                            'node wall (ms/frame)', 'path (ms/frame, mean)', 'path (ms, max)',
                            'path poses', 'odometry out'], rows)
    steady = blocks[1:]                       # after the start-up block
    frames = np.array([b['frames'] for b in steady], dtype=float)
    changes = {key: trend_change(frames, np.array([b[key] for b in steady]))
               for key in ('rss_mb', 'cpu_ms', 'node_ms')}
    path_mean = float(np.mean([b['path_ms'] for b in steady]))
    verdict = 'flat' if abs(changes['rss_mb']) <= 5.0 and abs(changes['cpu_ms']) <= 5.0 \
        else 'NOT flat'
    return '\n\n'.join([
        f'A {info["lap_frames"]}-frame lap of the rendered street ({info["camera"]}, rendered in '
        f'{info["render_s"]:.0f} s) driven round and round at 10 Hz through an in-process '
        f'PlanarVoNode (default parameters: path decimated to 1 m, at most 500 poses, '
        f'published once per second of image time to a subscriber: '
        f'{"yes" if info["path_subscribed"] else "NO (not matched)"}). One row per '
        f'{info["every"]} frames; times are medians over the block (node CPU: the thread time '
        f'of the image callback; node wall: its time_ms.node, which also carries the other '
        f'processes competing for the 2 cores).',
        table,
        f'Change over the drive after the first block (Theil-Sen line through the blocks): RSS '
        f'{changes["rss_mb"]:+.1f} %, node CPU time {changes["cpu_ms"]:+.1f} %, node wall time '
        f'{changes["node_ms"]:+.1f} %; path publishing {path_mean:.3f} ms per frame on '
        f'average. Verdict (memory and CPU time): **{verdict}** (target: within 5 %).',
        f'Node {info["summary"]}',
    ])
