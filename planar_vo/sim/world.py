"""A seeded street world made of textured rectangles: the ground, building facades, parked cars.

Every surface is a planar rectangle ("plane" below) in odom (REP-103, z up, ground ``z = 0``):
``X(a, b) = origin + a u + b v`` for ``0 <= a <= width``, ``0 <= b <= height`` metres, with unit
axes ``u``, ``v`` and normal ``n = u x v``. Closed boxes (buildings, cars) use outward normals and
are one-sided (back faces are culled); the ground is one large rectangle.

`StreetWorld.along` builds the street around any drive: buildings (boxes with random width,
depth, height and set-back) line both sides of the driven path, parked cars (two stacked boxes)
stand at the kerbs, and everything keeps a clearance from the path, so straights, turns,
S-curves, reversing and loops all get a plausible street without any map.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from planar_vo.core.checks import as_array
from planar_vo.core.trajectory import Trajectory
from planar_vo.errors import InputError
from planar_vo.sim.textures import DETAIL_TEXEL, FACADE, GROUND, TILE, VEHICLE

__all__ = ['StreetWorld', 'GROUND_KIND', 'FACADE_KIND', 'OBSTACLE_KIND']

logger = logging.getLogger(__name__)

GROUND_KIND, FACADE_KIND, OBSTACLE_KIND = 0, 1, 2

# Each plane scales the texel size by a random factor in this range so neighbours differ.
_TEXEL_JITTER = (0.85, 1.2)


@dataclass(frozen=True)
class StreetWorld:
    """Textured planar rectangles in odom (see the module docstring); build with `along`.

    Attributes (M planes):
        origin, axis_u, axis_v: ``(M, 3)``; rectangle corner and unit edge directions (odom).
        size: ``(M, 2)`` width along ``u`` and height along ``v`` (m).
        material: ``(M,)`` texture material (`planar_vo.sim.textures` GROUND/FACADE/VEHICLE).
        kind: ``(M,)`` what the plane is: GROUND_KIND, FACADE_KIND or OBSTACLE_KIND.
        one_sided: ``(M,)`` visible only from the side its normal points to.
        gain, bias: ``(M,)`` brightness of the plane: ``bias + gain * texture`` (grey levels).
        texture_map: ``(M, 2, 3)``: level-0 detail-layer texel coordinates are
            ``d = texture_map @ [a, b, 1]`` for plane coordinates ``(a, b)`` in metres.
        coarse_offset: ``(M, 2)``: coarse-layer texel coordinates are
            ``COARSE_FROM_DETAIL @ d + coarse_offset`` (`planar_vo.sim.textures`).
        seed: the seed of the layout and of the textures.
        max_range: planes whose nearest point is farther than this from the camera are not drawn
            (m); applied identically by `render` and the ground truth.
    """

    origin: np.ndarray
    axis_u: np.ndarray
    axis_v: np.ndarray
    size: np.ndarray
    material: np.ndarray
    kind: np.ndarray
    one_sided: np.ndarray
    gain: np.ndarray
    bias: np.ndarray
    texture_map: np.ndarray
    coarse_offset: np.ndarray
    seed: int = 0
    max_range: float = 250.0

    def __post_init__(self) -> None:
        m = len(self.origin)
        for name, shape in (('origin', (m, 3)), ('axis_u', (m, 3)), ('axis_v', (m, 3)),
                            ('size', (m, 2)), ('gain', (m,)), ('bias', (m,)),
                            ('texture_map', (m, 2, 3)), ('coarse_offset', (m, 2))):
            value = as_array(name, getattr(self, name), shape)
            value.setflags(write=False)
            object.__setattr__(self, name, value)
        for name, dtype in (('material', np.int64), ('kind', np.int64), ('one_sided', bool)):
            value = np.asarray(getattr(self, name)).astype(dtype)
            if value.shape != (m,):
                raise InputError(f'{name}: expected shape ({m},), got {value.shape}')
            value.setflags(write=False)
            object.__setattr__(self, name, value)
        if not np.allclose(np.einsum('ij,ij->i', self.axis_u, self.axis_v), 0.0, atol=1e-9):
            raise InputError('axis_u, axis_v: expected orthogonal unit axes per plane')
        if not (self.max_range > 0):
            raise InputError(f'max_range: expected a positive distance (m), got {self.max_range}')

    def __len__(self) -> int:
        return int(self.origin.shape[0])

    @property
    def normal(self) -> np.ndarray:
        """Unit normals ``u x v``, shape ``(M, 3)``."""
        return np.cross(self.axis_u, self.axis_v)

    @property
    def corners(self) -> np.ndarray:
        """Rectangle corners in odom, ``(M, 4, 3)``, in the order (0,0), (w,0), (w,h), (0,h)."""
        du = self.axis_u * self.size[:, :1]
        dv = self.axis_v * self.size[:, 1:]
        o = self.origin
        return np.stack([o, o + du, o + du + dv, o + dv], axis=1)

    # -- construction -----------------------------------------------------------------------

    @classmethod
    def along(cls, path: Trajectory | np.ndarray, seed: int = 0, *, margin: float = 150.0,
              setback: tuple[float, float] = (7.0, 10.0),
              building_width: tuple[float, float] = (8.0, 24.0),
              building_depth: tuple[float, float] = (8.0, 16.0),
              building_height: tuple[float, float] = (5.0, 22.0),
              gap: tuple[float, float] = (0.0, 6.0), buildings: bool = True,
              parked_car_probability: float = 0.5,
              car_offset: float = 3.8, clearance: float = 2.5,
              max_range: float = 250.0) -> StreetWorld:
        """A street around a drive: ground, buildings on both sides, parked cars at the kerbs.

        Args:
            path: a `Trajectory`, poses ``(N, 4, 4)`` or positions ``(N, 2)`` in odom (m).
            seed: layout and texture seed; the same seed and path give the same world.
            margin: the street continues this far (m) straight beyond both ends of the path.
            setback: range of the facades' distance from the path centre line (m).
            building_width, building_depth, building_height: ranges of box sizes (m).
            gap: range of the gaps between neighbouring buildings (m).
            buildings: False for an open ground plane with (optionally) parked cars only.
            parked_car_probability: chance of a parked car at each kerb slot (6 m).
            car_offset: distance of parked cars' centres from the path centre line (m).
            clearance: nothing is placed within this distance of the path centre line (m),
                except the ground.
            max_range: drawing range (see the class attributes).
        """
        for name, value in (('margin', margin), ('clearance', clearance),
                            ('car_offset', car_offset)):
            if not (np.isfinite(value) and value >= 0.0):
                raise InputError(f'{name}: expected a non-negative distance (m), got {value!r}')
        for name, (lo, hi) in (('setback', setback), ('building_width', building_width),
                               ('building_depth', building_depth),
                               ('building_height', building_height), ('gap', gap)):
            if not (np.isfinite([lo, hi]).all() and 0.0 <= lo <= hi):
                raise InputError(f'{name}: expected a range 0 <= low <= high (m), got '
                                 f'{(lo, hi)!r}')
        if not 0.0 <= parked_car_probability <= 1.0:
            raise InputError(f'parked_car_probability: expected a probability in [0, 1], got '
                             f'{parked_car_probability!r}')
        if building_width[0] <= 0.0:
            raise InputError(f'building_width: expected a positive minimum width (m), got '
                             f'{building_width!r}')
        lines = _street_lines(path, margin)
        rng = np.random.default_rng([seed, 0x5731])
        builder = _Builder(rng, np.concatenate([line for line, _ in lines]), clearance)
        # Ground: a rectangle covering the whole street plus the drawing range around it.
        lo = builder.centre.min(axis=0) - max_range
        hi = builder.centre.max(axis=0) + max_range
        builder.add_plane(np.r_[lo, 0.0], [1, 0, 0], [0, 1, 0], hi - lo, GROUND, GROUND_KIND,
                          one_sided=True, rot_spread=np.pi)
        for centre, heading in lines:
            arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(centre, axis=0),
                                                                  axis=1))])
            for side in (1.0, -1.0):
                s = rng.uniform(0.0, building_width[1]) if buildings else np.inf
                while s < arc[-1]:
                    width = rng.uniform(*building_width)
                    depth = rng.uniform(*building_depth)
                    height = rng.uniform(*building_height)
                    offset = rng.uniform(*setback)
                    p, psi = _at(arc, centre, heading, s + width / 2)
                    normal = np.array([-np.sin(psi), np.cos(psi)]) * side
                    builder.add_box(p + normal * (offset + depth / 2), psi, width, depth, 0.0,
                                    height, FACADE, FACADE_KIND, top=False)
                    s += width + rng.uniform(*gap)
                s = rng.uniform(0.0, 6.0)
                while s < arc[-1]:
                    if rng.uniform() < parked_car_probability:
                        p, psi = _at(arc, centre, heading, s)
                        normal = np.array([-np.sin(psi), np.cos(psi)]) * side
                        psi += rng.normal(0.0, 0.03)
                        centre_xy = p + normal * (car_offset + rng.normal(0.0, 0.1))
                        length, width = rng.uniform(3.8, 4.8), rng.uniform(1.7, 1.9)
                        shift = np.array([np.cos(psi), np.sin(psi)]) * rng.uniform(-0.5, 0.0)
                        cabin_height = rng.uniform(1.35, 1.5)
                        if builder.add_box(centre_xy, psi, length, width, 0.0, 1.0, VEHICLE,
                                           OBSTACLE_KIND, top=True):
                            builder.add_box(centre_xy + shift, psi, length * 0.55, width * 0.9,
                                            1.0, cabin_height, VEHICLE, OBSTACLE_KIND, top=True,
                                            stacked=True)
                    s += 6.0
        world = builder.build(seed, max_range)
        logger.debug('StreetWorld.along: %d planes, %d boxes skipped', len(world),
                     builder.skipped)
        return world


def _street_lines(path: Trajectory | np.ndarray, margin: float
                  ) -> list[tuple[np.ndarray, np.ndarray]]:
    """Centre lines of the street: the driven path resampled every metre, then straight roads
    of length ``margin`` ahead of and behind the first and the last pose (along their headings,
    so a drive that ends reversing still looks down a street).

    Returns ``(positions (K, 2), direction of the line (K,) rad)`` per line.
    """
    if isinstance(path, Trajectory):
        xy, yaw = path.xy, path.yaw[[0, -1]]
    else:
        arr = np.asarray(path, dtype=np.float64)
        if arr.ndim == 3:
            xy = as_array('path', arr, (None, 4, 4))[:, :2, 3]
            yaw = np.arctan2(arr[[0, -1], 1, 0], arr[[0, -1], 0, 0])
        else:
            xy = as_array('path', arr, (None, 2))
            d = np.diff(xy, axis=0)
            moving = np.flatnonzero(np.linalg.norm(d, axis=1) > 1e-6)
            first, last = (d[moving[0]], d[moving[-1]]) if moving.size else ([1, 0], [1, 0])
            yaw = np.array([np.arctan2(first[1], first[0]), np.arctan2(last[1], last[0])])
    step = np.linalg.norm(np.diff(xy, axis=0), axis=1)
    xy = np.concatenate([xy[:1], xy[1:][step > 1e-6]])
    lines = []
    if len(xy) > 1:
        arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(xy, axis=0), axis=1))])
        s = np.linspace(0.0, arc[-1], max(2, int(np.ceil(arc[-1])) + 1))
        line = np.stack([np.interp(s, arc, xy[:, 0]), np.interp(s, arc, xy[:, 1])], -1)
        d = np.gradient(line, axis=0)
        lines.append((line, np.arctan2(d[:, 1], d[:, 0])))
    ray = np.arange(0.0, margin + 1.0)[:, None]
    for start, heading in ((xy[0], yaw[0]), (xy[-1], yaw[-1])):
        for direction in (heading, heading + np.pi):
            lines.append((start + ray * [np.cos(direction), np.sin(direction)],
                          np.full(len(ray), direction)))
    return lines


def _at(arc: np.ndarray, line: np.ndarray, heading: np.ndarray, s: float
        ) -> tuple[np.ndarray, float]:
    k = int(np.clip(np.searchsorted(arc, s), 0, len(arc) - 1))
    return line[k], float(heading[k])


class _Builder:
    """Collects planes and boxes, rejecting boxes that block the path or overlap earlier boxes."""

    def __init__(self, rng: np.random.Generator, centre: np.ndarray, clearance: float) -> None:
        self.rng = rng
        self.centre = centre
        self.clearance = clearance
        self.planes: list[tuple] = []
        self.footprints: list[np.ndarray] = []            # (4, 2) corners of placed boxes
        self.skipped = 0

    def add_plane(self, origin, u, v, size, material: int, kind: int, *, one_sided: bool,
                  rot_spread: float, gain: float = 1.0, bias: float = 128.0) -> None:
        rng = self.rng
        angle = rng.uniform(-rot_spread, rot_spread)
        scale = 1.0 / (DETAIL_TEXEL * rng.uniform(*_TEXEL_JITTER))
        c, s = np.cos(angle) * scale, np.sin(angle) * scale
        tex = np.array([[c, -s, rng.uniform(0, TILE)], [s, c, rng.uniform(0, TILE)]])
        self.planes.append((np.asarray(origin, float), np.asarray(u, float),
                            np.asarray(v, float), np.asarray(size, float), material, kind,
                            one_sided, gain, bias, tex, rng.uniform(0, TILE, 2)))

    def _blocked(self, corners: np.ndarray) -> bool:
        """Whether a footprint comes within `clearance` of the path or overlaps a placed box."""
        c = corners.mean(axis=0)
        ex = corners[1] - corners[0]
        ey = corners[3] - corners[0]
        half = np.array([np.linalg.norm(ex), np.linalg.norm(ey)]) / 2
        axes = np.stack([ex / (2 * half[0]), ey / (2 * half[1])])
        local = np.abs((self.centre - c) @ axes.T)
        gap = np.linalg.norm(np.maximum(local - half, 0.0), axis=1)
        if np.any(gap < self.clearance):
            return True
        return any(_overlap(corners, other) for other in self.footprints)

    def add_box(self, centre_xy, psi: float, length: float, width: float, z0: float, z1: float,
                material: int, kind: int, *, top: bool, stacked: bool = False) -> bool:
        """An oriented box; faces get outward normals and are one-sided.

        Returns whether it was placed. A ``stacked`` box sits on the previous one and skips the
        blocking test.
        """
        ex = np.array([np.cos(psi), np.sin(psi)])
        ey = np.array([-np.sin(psi), np.cos(psi)])
        hx, hy = ex * length / 2, ey * width / 2
        corners = np.stack([centre_xy - hx - hy, centre_xy + hx - hy, centre_xy + hx + hy,
                            centre_xy - hx + hy])
        gain = self.rng.uniform(0.7, 1.15)
        bias = self.rng.uniform(100.0, 155.0)
        if not stacked:
            if self._blocked(corners):
                self.skipped += 1
                return False
            self.footprints.append(corners)
        up = np.array([0.0, 0.0, 1.0])
        for k in range(4):
            a, b = corners[k], corners[(k + 1) % 4]          # counter-clockwise: outward = right
            u = np.r_[b - a, 0.0]
            w = np.linalg.norm(u)
            # Face shading: a small per-face brightness change makes box edges visible.
            self.add_plane(np.r_[a, z0], u / w, up, (w, z1 - z0), material, kind, one_sided=True,
                           rot_spread=0.05, gain=gain, bias=bias + self.rng.uniform(-12, 12))
        if top:
            self.add_plane(np.r_[corners[0], z1], np.r_[ex, 0.0], np.r_[ey, 0.0],
                           (length, width), material, kind, one_sided=True, rot_spread=np.pi,
                           gain=gain, bias=bias + 10.0)
        return True

    def build(self, seed: int, max_range: float) -> StreetWorld:
        cols = list(zip(*self.planes))
        return StreetWorld(np.array(cols[0]), np.array(cols[1]), np.array(cols[2]),
                           np.array(cols[3]), np.array(cols[4]), np.array(cols[5]),
                           np.array(cols[6]), np.array(cols[7], float), np.array(cols[8], float),
                           np.array(cols[9]), np.array(cols[10]), int(seed), float(max_range))


def _overlap(a: np.ndarray, b: np.ndarray) -> bool:
    """Separating-axis test of two convex quadrilaterals ``(4, 2)``."""
    for poly in (a, b):
        edges = np.roll(poly, -1, axis=0) - poly
        normals = np.stack([-edges[:, 1], edges[:, 0]], -1)
        pa, pb = a @ normals.T, b @ normals.T
        if np.any((pa.max(0) <= pb.min(0)) | (pb.max(0) <= pa.min(0))):
            return False
    return True
