"""ROS 2 test tools: a bag player process, an in-process topic probe, node process helpers.

The player runs in its own process, like ``ros2 bag play`` would::

    python test/ros_tools.py play BAG [--topics T ...] [--compress png|jpeg] [--rate R]
                                      [--reliable] [--hold]

and measures the node's CPU time while a bag plays into it (a benchmark figure, not a test)::

    python test/ros_tools.py node-cpu BAG [--topics T ...] [NODE ARGUMENTS ...]

It reads the bag with `planar_vo.io`, waits until every publisher has a matched subscriber,
then publishes the Image, CompressedImage, CameraInfo, TwistStamped and Odometry messages of the
chosen topics in log-time order at the recorded rate (header stamps as recorded), and prints
``played N``. Publishers use the sensor-data QoS of camera drivers (best effort), or reliable
delivery with ``--reliable``. ``--compress`` turns Image topics into ``<topic>/compressed``
CompressedImage messages. With ``--hold`` it then stays up until SIGINT/SIGTERM, so that no
message is lost to a publisher going away before delivery.

`Probe` subscribes in the test process (its own rclpy context, no signal handlers) and spins
until a condition holds or a timeout expires; `NodeProcess` starts ``<prefix>/lib/planar_vo/<exe>``
exactly as ``ros2 run`` does and always cleans up; `free_domain_id` picks a ROS domain for one
run.
"""

from __future__ import annotations

import argparse
import importlib
import os
import random
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
PLAYED_TYPES = ('sensor_msgs/msg/Image', 'sensor_msgs/msg/CompressedImage',
                'sensor_msgs/msg/CameraInfo', 'geometry_msgs/msg/TwistStamped',
                'nav_msgs/msg/Odometry')


# Fast DDS ports of domain d: 7400 + 250 d + (0 .. 249) (the RTPS port mapping); its
# shared-memory transport keeps one segment and one mutex per port in /dev/shm.
_DDS_PORT_BASE, _DDS_DOMAIN_GAIN = 7400, 250
SHM_DIR = Path('/dev/shm')


def free_domain_id(low: int, high: int, rng: random.Random | None = None,
                   shm_dir: Path = SHM_DIR) -> int:
    """A random ROS domain id in ``[low, high]`` whose Fast DDS ports have no shared-memory
    files in ``shm_dir``, or any id of the range when every one has some.

    Why: a process killed before it cleans up leaves its segments and mutexes behind
    (``fastrtps_port<P>``, ``sem.fastrtps_port<P>_mutex``); a later run on the same domain
    reuses those ports. Two full test runs on a machine with such leftovers lost images
    part-way in a node test, and passed after the leftovers were removed (not proven to be the
    cause; a domain without leftovers costs nothing)."""
    rng = rng or random.SystemRandom()
    taken = set()
    try:
        names = [p.name for p in shm_dir.iterdir()]
    except OSError:
        names = []
    for name in names:
        digits = name.removeprefix('sem.').removeprefix('fastrtps_port').removesuffix('_mutex')
        if name != digits and digits.isdigit():
            taken.add((int(digits) - _DDS_PORT_BASE) // _DDS_DOMAIN_GAIN)
    ids = list(range(low, high + 1))
    free = [d for d in ids if d not in taken]
    return rng.choice(free or ids)


# -- message conversion ----------------------------------------------------------------------------

def rclpy_class(msgtype: str) -> type:
    """The rclpy class of ``'pkg/msg/Name'``."""
    package, _, name = msgtype.split('/')
    return getattr(importlib.import_module(f'{package}.msg'), name)


def to_rclpy(src: Any, cls: type) -> Any:
    """A rosbags message as an rclpy message of class ``cls``, field by field (nested ok)."""
    out = cls()
    for name in cls.get_fields_and_field_types():
        value = getattr(src, name)
        current = getattr(out, name)
        if hasattr(current, 'get_fields_and_field_types'):
            value = to_rclpy(value, type(current))
        elif isinstance(value, np.ndarray) and value.dtype == np.uint8:
            value = value.tobytes()          # fast path for image buffers
        setattr(out, name, value)
    return out


def compress(msg: Any, fmt: str) -> Any:
    """A rosbags ``sensor_msgs/Image`` as an rclpy ``CompressedImage`` (``png`` or ``jpeg``)."""
    import cv2
    from sensor_msgs.msg import CompressedImage

    from planar_vo.ros.messages import image_to_array

    pixels = image_to_array(msg, gray=False)
    if pixels.ndim == 3 and msg.encoding.startswith('rgb'):
        pixels = cv2.cvtColor(pixels, cv2.COLOR_RGB2BGR)
    ok, data = cv2.imencode('.png' if fmt == 'png' else '.jpg', pixels,
                            [] if fmt == 'png' else [cv2.IMWRITE_JPEG_QUALITY, 95])
    assert ok, f'cannot encode a {msg.encoding} image as {fmt}'
    out = CompressedImage()
    out.header = to_rclpy(msg.header, type(out.header))
    out.format = f'{msg.encoding}; {fmt} compressed {msg.encoding}'
    out.data = data.tobytes()
    return out


# -- the player ------------------------------------------------------------------------------------

def play(bag_path: str, topics: list[str] | None, compress_fmt: str | None, rate: float,
         reliable: bool, hold: bool, timeout: float) -> int:
    """Publish a bag's camera (and speed) topics at the recorded rate; see the module docstring."""
    import rclpy
    from rclpy.executors import ExternalShutdownException
    from rclpy.qos import qos_profile_sensor_data

    from planar_vo.io import open_bag

    rclpy.init()
    node = rclpy.create_node('bag_player')
    qos = 10 if reliable else qos_profile_sensor_data
    try:
        with open_bag(bag_path) as bag:
            chosen = topics or [t for t, m in bag.topics.items() if m in PLAYED_TYPES]
            publishers = {}
            for topic in chosen:
                bag.require_topic('topics', topic, PLAYED_TYPES)
                msgtype = bag.topics[topic]
                if compress_fmt and msgtype == 'sensor_msgs/msg/Image':
                    publishers[topic] = (node.create_publisher(
                        rclpy_class('sensor_msgs/msg/CompressedImage'), f'{topic}/compressed',
                        qos), None)
                else:
                    publishers[topic] = (node.create_publisher(
                        rclpy_class(msgtype), topic, qos), rclpy_class(msgtype))
            deadline = time.monotonic() + timeout
            while any(p.get_subscription_count() == 0 for p, _ in publishers.values()):
                if time.monotonic() > deadline:
                    waiting = [p.topic_name for p, _ in publishers.values()
                               if p.get_subscription_count() == 0]
                    print(f'player: no subscriber on {", ".join(waiting)} after {timeout} s '
                          f'(it waits for one on every topic it plays: choose them with '
                          f'--topics)', file=sys.stderr)
                    return 1
                rclpy.spin_once(node, timeout_sec=0.02)
            print('player: ready', flush=True)
            count = 0
            start, first = time.monotonic(), None
            for message in bag.messages(chosen):
                first = message.log_time_ns if first is None else first
                due = start + (message.log_time_ns - first) / 1e9 / rate
                time.sleep(max(0.0, due - time.monotonic()))       # pacing, not waiting
                publisher, cls = publishers[message.topic]
                msg = bag.deserialize(message)
                publisher.publish(compress(msg, compress_fmt) if cls is None else
                                  to_rclpy(msg, cls))
                count += 1
        print(f'played {count}', flush=True)
        if hold:
            rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


# -- in-process probe ------------------------------------------------------------------------------

class Probe:
    """Subscribes to topics in the test process and spins until conditions hold.

    Args:
        env: the ROS environment (domain id, discovery profile) to join; applied to
            ``os.environ`` for the lifetime of the probe.
    """

    def __init__(self, env: Mapping[str, str]) -> None:
        import rclpy
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.signals import SignalHandlerOptions

        self._saved = {k: os.environ.get(k) for k in env}
        os.environ.update(env)
        self.context = Context()
        # args=[]: the probe's process arguments (node-cpu's node arguments, pytest's) are
        # not ROS arguments of the probe.
        rclpy.init(args=[], context=self.context,
                   signal_handler_options=SignalHandlerOptions.NO)
        self.node = rclpy.create_node('test_probe', context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.messages: dict[str, list[Any]] = {}
        self._subscriptions: dict[str, Any] = {}

    def __enter__(self) -> Probe:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        self.context.try_shutdown()
        for key, value in self._saved.items():
            if value is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = value

    def subscribe(self, topic: str, msg_class: type, qos: Any = 10) -> list[Any]:
        """Collect messages of ``topic``; returns the (growing) list."""
        received: list[Any] = []
        self.messages[topic] = received
        self._subscriptions[topic] = self.node.create_subscription(
            msg_class, topic, received.append, qos)
        return received

    def spin_until(self, condition: Callable[[], bool], timeout: float, what: str,
                   alive: Iterable[NodeProcess | subprocess.Popen] = ()) -> None:
        """Spin until ``condition()``; AssertionError naming ``what`` on timeout or when a
        process in ``alive`` exits early."""
        deadline = time.monotonic() + timeout
        while not condition():
            for proc in alive:
                popen = proc.popen if isinstance(proc, NodeProcess) else proc
                if popen.poll() is not None and popen.returncode != 0:
                    detail = proc.output() if isinstance(proc, NodeProcess) else ''
                    raise AssertionError(f'waiting for {what}: process {popen.args[0]} exited '
                                         f'with {popen.returncode}\n{detail[-3000:]}')
            if time.monotonic() > deadline:
                logs = '\n'.join(f'--- {p.popen.args[0]}:\n{p.output()[-3000:]}' for p in alive
                                 if isinstance(p, NodeProcess))
                raise AssertionError(f'timed out after {timeout} s waiting for {what}\n{logs}')
            self.executor.spin_once(timeout_sec=0.02)

    def call(self, srv_type: type, name: str, request: Any, timeout: float = 20.0) -> Any:
        """Call a service and return its response (waits for the server first)."""
        client = self.node.create_client(srv_type, name)
        try:
            self.spin_until(client.service_is_ready, timeout, f'service {name}')
            future = client.call_async(request)
            self.spin_until(future.done, timeout, f'the response of {name}')
            return future.result()
        finally:
            self.node.destroy_client(client)

    def wait_for_publisher(self, topic: str, timeout: float = 20.0, **kwargs: Any) -> None:
        """Until a publisher is matched to our subscription of ``topic``."""
        sub = self._subscriptions[topic]
        self.spin_until(lambda: sub.get_publisher_count() > 0, timeout,
                        f'a publisher on {topic}', **kwargs)


# -- processes -------------------------------------------------------------------------------------

class NodeProcess:
    """A process with its output in a file (no pipe to fill up); `stop` signals and waits,
    `close` kills whatever is left."""

    def __init__(self, args: list[str], env: Mapping[str, str], log_path: Path) -> None:
        self.log_path = Path(log_path)
        self._log = open(self.log_path, 'w')
        self.popen = subprocess.Popen(args, env=dict(env), stdout=self._log,
                                      stderr=subprocess.STDOUT, text=True, cwd=ROOT)

    def output(self) -> str:
        self._log.flush()
        return self.log_path.read_text()

    def stop(self, sig: int = signal.SIGINT, timeout: float = 20.0) -> int:
        """Send ``sig`` and wait for the exit code."""
        if self.popen.poll() is None:
            self.popen.send_signal(sig)
        return self.popen.wait(timeout=timeout)

    def close(self) -> None:
        if self.popen.poll() is None:
            self.popen.terminate()
            try:
                self.popen.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.popen.kill()
                self.popen.wait()
        self._log.close()

    def __enter__(self) -> NodeProcess:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def player_args(bag: Path, *, topics: Iterable[str] = (), compress_fmt: str | None = None,
                rate: float = 1.0, reliable: bool = False, hold: bool = True) -> list[str]:
    """Command line of the bag player (this file) in the current interpreter."""
    args = [sys.executable, str(Path(__file__).resolve()), 'play', str(bag), '--rate', str(rate)]
    if topics:
        args += ['--topics', *topics]
    if compress_fmt:
        args += ['--compress', compress_fmt]
    if reliable:
        args.append('--reliable')
    if hold:
        args.append('--hold')
    return args


def node_cpu(bag: Path, topics: list[str], node_args: list[str]) -> int:
    """Play ``bag`` at its recorded rate into the installed node and compare the node's CPU
    time (utime + stime of /proc/<pid>/stat, all its threads) with the processing time it
    reports per frame (``time_ms.node`` of ``status``), from the first status to the end."""
    env = dict(os.environ, ROS_DOMAIN_ID=str(free_domain_id(101, 200)),
               ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST', PYTHONUNBUFFERED='1')
    env['PATH'] = str(Path(sys.executable).parent) + os.pathsep + env.get('PATH', '')
    exe = Path(sys.prefix) / 'lib/planar_vo/planar_vo_node'

    def cpu_seconds(pid: int) -> float:
        fields = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')

    with tempfile_dir() as tmp, Probe(env) as probe, \
            NodeProcess([str(exe), '--ros-args', *node_args], env, tmp / 'node.log') as node:
        status = probe.subscribe('/status', rclpy_class('diagnostic_msgs/msg/DiagnosticArray'))
        probe.wait_for_publisher('/status', alive=[node])
        with NodeProcess(player_args(bag, topics=topics), env, tmp / 'player.log') as player:
            probe.spin_until(lambda: len(status) >= 1, 60.0, 'the first frame',
                             alive=[node, player])
            cpu0, wall0, first = cpu_seconds(node.popen.pid), time.monotonic(), len(status)
            probe.spin_until(lambda: 'played' in player.output(), 3600.0, 'the end of the bag',
                             alive=[node, player])
            count = -1
            while count != len(status):                  # until the node has caught up
                count, end = len(status), time.monotonic() + 0.5
                probe.spin_until(lambda: time.monotonic() > end, 5.0, 'the last frames')
            cpu, wall = cpu_seconds(node.popen.pid) - cpu0, time.monotonic() - wall0
            last = len(status)
        node.stop()
    frames = status[first:last]
    work = sum(float(kv.value) for s in frames for kv in s.status[0].values
               if kv.key == 'time_ms.node') / 1e3
    print(f'node-cpu: {len(frames)} frames in {wall:.1f} s; node CPU {cpu:.2f} s '
          f'({100 * cpu / wall:.0f} % of a core); processing {work:.2f} s '
          f'({1e3 * work / max(len(frames), 1):.1f} ms per frame); CPU / processing '
          f'{cpu / work:.2f}')
    return 0


def tempfile_dir():
    """A temporary directory as a context manager yielding a Path."""
    import contextlib
    import tempfile

    @contextlib.contextmanager
    def manager():
        with tempfile.TemporaryDirectory() as tmp:
            yield Path(tmp)
    return manager()


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    sub = parser.add_subparsers(dest='command', required=True)
    p = sub.add_parser('play', help='publish a bag at the recorded rate')
    p.add_argument('bag')
    p.add_argument('--topics', nargs='+', help='topics to play (default: all playable)')
    p.add_argument('--compress', choices=('png', 'jpeg'),
                   help='publish Image topics as <topic>/compressed')
    p.add_argument('--rate', type=float, default=1.0, help='playback speed factor')
    p.add_argument('--reliable', action='store_true',
                   help='reliable publishers (default: sensor-data QoS, best effort)')
    p.add_argument('--hold', action='store_true', help='stay up after playing until a signal')
    p.add_argument('--timeout', type=float, default=20.0,
                   help='seconds to wait for subscribers')
    c = sub.add_parser('node-cpu', help='the node\'s CPU time while a bag plays into it')
    c.add_argument('bag', type=Path)
    c.add_argument('--topics', nargs='+', default=['/camera/image_raw', '/camera/camera_info'])
    c.add_argument('node_args', nargs=argparse.REMAINDER,
                   help='node arguments after --ros-args (default: the camera remaps)')
    args = parser.parse_args(argv)
    if args.command == 'node-cpu':
        return node_cpu(args.bag, args.topics, args.node_args or [
            '-r', 'image:=/camera/image_raw', '-r', 'camera_info:=/camera/camera_info'])
    return play(args.bag, args.topics, args.compress, args.rate, args.reliable, args.hold,
                args.timeout)


if __name__ == '__main__':
    sys.exit(main())
