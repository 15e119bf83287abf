"""`Trajectory`: stamped rigid poses, the one type for estimates, ground truth and rendered drives.

Stamps are integer nanoseconds, so that a stamp written to a bag or a TUM file and read back is
unchanged; poses are 4x4 ``T_world_body`` (`planar_vo.core.conventions`). For a vehicle,
``T_odom_base`` (REP-103: x forward, y left, z up; positive yaw turns left).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from planar_vo.core.checks import as_array
from planar_vo.core.conventions import (
    invert,
    mount_transform,
    quaternion_from_rotation,
    rotation_from_quaternion,
    se3,
    yaw_of,
)
from planar_vo.errors import InputError

__all__ = ['ROTATION_TOLERANCE', 'Trajectory', 'concatenate', 'rotation_defects']

_NS_PER_S = 1_000_000_000


# Largest |R^T R - I| entry of a rotation block (KITTI's poses.txt writes them to about 1e-6;
# composed poses drift by rounding only).
ROTATION_TOLERANCE = 1e-3


def rotation_defects(R: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For ``(N, 3, 3)`` blocks: the indices of those that are not rotations (``R^T R`` off the
    identity by more than `ROTATION_TOLERANCE`, or determinant not positive), and every
    block's largest ``|R^T R - I|`` entry and determinant (for the message)."""
    error = np.abs(np.einsum('nji,njk->nik', R, R) - np.eye(3)).max(axis=(1, 2))
    det = np.linalg.det(R)
    return np.flatnonzero((error > ROTATION_TOLERANCE) | ~(det > 0.0)), error, det


def _check_rigid(poses: np.ndarray) -> None:
    """`InputError` unless every ``(4, 4)`` pose is a rigid transform: bottom row ``[0, 0, 0,
    1]``, rotation block orthonormal with determinant +1 (a scaled or mirrored block would be
    evaluated as some other trajectory without a word; a user test)."""
    if not len(poses):
        return
    bottom = np.abs(poses[:, 3] - (0.0, 0.0, 0.0, 1.0)).max(axis=1)
    rotations, error, det = rotation_defects(poses[:, :3, :3])
    bad = np.union1d(rotations, np.flatnonzero(bottom > 1e-9))
    if bad.size:
        k = int(bad[0])
        raise InputError(f'poses: expected rigid transforms (rotation block orthonormal with '
                         f'determinant +1, bottom row [0, 0, 0, 1]), got pose {k} with R^T R off '
                         f'the identity by {error[k]:.3g}, determinant {det[k]:.3g} and bottom '
                         f'row {poses[k, 3].tolist()}')


@dataclass(frozen=True, eq=False)
class Trajectory:
    """Stamped poses ``T_world_body``.

    Attributes:
        stamps_ns: ``(N,)`` int64 stamps in nanoseconds, strictly increasing.
        poses: ``(N, 4, 4)`` rigid transforms.

    Build from float seconds or from positions and quaternions with `from_poses` and
    `from_quaternions`.
    """

    stamps_ns: np.ndarray
    poses: np.ndarray

    def __post_init__(self) -> None:
        stamps = np.asarray(self.stamps_ns)
        if stamps.ndim != 1 or not (stamps.size == 0 or np.issubdtype(stamps.dtype, np.integer)):
            raise InputError(f'stamps_ns: expected a 1-D integer array, got {stamps.dtype} '
                             f'shape {stamps.shape}')
        poses = as_array('poses', self.poses, (stamps.shape[0], 4, 4), min_items=0)
        _check_rigid(poses)
        if np.any(np.diff(stamps) <= 0):
            raise InputError('stamps: expected strictly increasing times, got a non-increasing '
                             'step')
        for name, value in (('stamps_ns', stamps.astype(np.int64)), ('poses', poses)):
            value = np.array(value)
            value.setflags(write=False)
            object.__setattr__(self, name, value)

    # -- construction --------------------------------------------------------------------------

    @classmethod
    def from_poses(cls, stamps: np.ndarray, poses: np.ndarray) -> Trajectory:
        """From stamps (integer array: ns; float array: seconds) and ``(N, 4, 4)`` poses."""
        stamps = np.asarray(stamps)
        if stamps.size and not np.issubdtype(stamps.dtype, np.integer):
            stamps = np.round(stamps.astype(np.float64) * 1e9).astype(np.int64)
        return cls(stamps.astype(np.int64), poses)

    @classmethod
    def from_quaternions(cls, stamps_ns: np.ndarray, positions: np.ndarray,
                         quaternions: np.ndarray) -> Trajectory:
        """From ``(N,)`` integer ns stamps, ``(N, 3)`` positions and ``(N, 4)`` quaternions
        ``(x, y, z, w)`` (normalised here; a zero quaternion is an `InputError`)."""
        stamps = np.asarray(stamps_ns)
        if stamps.ndim != 1 or not (stamps.size == 0 or np.issubdtype(stamps.dtype, np.integer)):
            raise InputError(f'stamps_ns: expected a 1-D integer array, got {stamps.dtype} '
                             f'shape {stamps.shape}')
        n = stamps.shape[0]
        positions = as_array('positions', positions, (n, 3), min_items=0)
        quaternions = as_array('quaternions', quaternions, (n, 4), min_items=0)
        norms = np.linalg.norm(quaternions, axis=1)
        if np.any(norms < 1e-9):
            raise InputError(f'quaternions: expected non-zero quaternions, got a zero one at '
                             f'index {int(np.argmin(norms))}')
        unit = quaternions / norms[:, None]
        trajectory = cls(stamps, se3(rotation_from_quaternion(unit).reshape(-1, 3, 3),
                                     positions).reshape(-1, 4, 4))
        # The given quaternions are kept (not recomputed from the rotations), so that a
        # trajectory read from a file and written back is unchanged to the last bit.
        unit.setflags(write=False)
        trajectory.__dict__['quaternions'] = unit
        return trajectory

    def __len__(self) -> int:
        return int(self.stamps_ns.shape[0])

    # -- views ---------------------------------------------------------------------------------

    @property
    def stamps(self) -> np.ndarray:
        """``(N,)`` stamps in seconds (float64)."""
        return self.stamps_ns / _NS_PER_S

    @property
    def positions(self) -> np.ndarray:
        """``(N, 3)`` positions (m)."""
        return self.poses[:, :3, 3]

    @property
    def rotations(self) -> np.ndarray:
        """``(N, 3, 3)`` rotation matrices."""
        return self.poses[:, :3, :3]

    @cached_property
    def quaternions(self) -> np.ndarray:
        """``(N, 4)`` unit quaternions ``(x, y, z, w)`` (``w >= 0`` unless given otherwise)."""
        q = quaternion_from_rotation(self.rotations).reshape(-1, 4)
        q.setflags(write=False)
        return q

    @property
    def xy(self) -> np.ndarray:
        """Positions in the ground plane, shape ``(N, 2)`` (m)."""
        return self.poses[:, :2, 3]

    @property
    def yaw(self) -> np.ndarray:
        """Headings (rad, wrapped to ``(-pi, pi]``), shape ``(N,)``."""
        return yaw_of(self.rotations)

    @property
    def rate(self) -> float:
        """Mean frame rate (Hz)."""
        if len(self) < 2:
            return 0.0
        return float((len(self) - 1) * _NS_PER_S / (self.stamps_ns[-1] - self.stamps_ns[0]))

    @property
    def path_length(self) -> float:
        """Length of the polyline through the positions (metres)."""
        return float(np.sum(np.linalg.norm(np.diff(self.positions, axis=0), axis=1)))

    def relative(self, i: int, j: int) -> np.ndarray:
        """Body motion ``T_body_i_body_j`` between poses ``i`` and ``j`` (4x4)."""
        return invert(self.poses[i]) @ self.poses[j]

    def camera_poses(self, mount) -> np.ndarray:
        """``T_world_camera = T_world_base @ T_base_camera`` per pose, shape ``(N, 4, 4)``.

        Args:
            mount: ``T_base_camera`` (4x4, `planar_vo.core.conventions.mount_transform`) or a
                `planar_vo.config.MountConfig` (anything with its x, y, height, roll, pitch,
                yaw).
        """
        if all(hasattr(mount, k) for k in ('x', 'y', 'height', 'roll', 'pitch', 'yaw')):
            mount = mount_transform(mount.x, mount.y, mount.height, mount.roll, mount.pitch,
                                    mount.yaw)
        T_bc = as_array('T_base_camera', mount, (4, 4))
        return self.poses @ T_bc

    # -- new trajectories ----------------------------------------------------------------------

    def subset(self, index: np.ndarray | slice) -> Trajectory:
        """The poses at `index` (integer indices, a boolean mask or a slice)."""
        return Trajectory(self.stamps_ns[index], self.poses[index])

    def transformed(self, R: np.ndarray, t: np.ndarray, scale: float = 1.0) -> Trajectory:
        """The trajectory in another world frame: ``p' = s R p + t``, ``R_i' = R R_i``."""
        R = as_array('R', R, (3, 3))
        t = as_array('t', t, (3,))
        return Trajectory(self.stamps_ns, se3(R @ self.rotations,
                                              scale * self.positions @ R.T + t))

    def shifted(self, offset_ns: int) -> Trajectory:
        """The same poses with ``offset_ns`` nanoseconds added to every stamp."""
        return Trajectory(self.stamps_ns + int(offset_ns), self.poses)

    def then(self, *others: Trajectory) -> Trajectory:
        """This trajectory followed by others (see `concatenate`)."""
        return concatenate(self, *others)


def concatenate(*segments: Trajectory) -> Trajectory:
    """Chain segments: each starts at the previous segment's last pose and time.

    The first pose of every later segment coincides with the last pose of the one before (both
    are that segment's origin) and is dropped, so no pose is duplicated.
    """
    if not segments:
        raise InputError('segments: expected at least one Trajectory, got none')
    stamps, poses = [segments[0].stamps_ns], [segments[0].poses]
    for seg in segments[1:]:
        if not isinstance(seg, Trajectory):
            raise InputError(f'segments: expected Trajectory objects, got {type(seg).__name__}')
        M = poses[-1][-1] @ invert(seg.poses[0])
        moved = seg.transformed(M[:3, :3], M[:3, 3]).shifted(stamps[-1][-1] - seg.stamps_ns[0])
        stamps.append(moved.stamps_ns[1:])
        poses.append(moved.poses[1:])
    return Trajectory(np.concatenate(stamps), np.concatenate(poses))
