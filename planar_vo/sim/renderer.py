"""Ray-cast rendering of a `StreetWorld` through a `CameraModel`, with anti-aliased textures.

Per pixel ``p`` (pixel centres at integer coordinates, OpenCV convention) the viewing ray is
``r = [q, 1]`` with ``q = camera.pixel_to_normalized(p)`` (undistorted, ideal normalised
coordinates), so lens distortion is rendered exactly. For a plane ``n . X = d`` in the camera
frame the inverse depth along ``r`` is linear in ``q``: ``1 / z = (n / d) . r``; the plane
coordinates are ``a = (g_a . r) / (g_n . r)`` with ``g_a = u - (u . o) n / d`` (a plane-to-image
homography), so visibility is a z-buffer over planes and texturing is a per-pixel homography.

Anti-aliasing: the texture footprint of a pixel is the Jacobian ``J = d(s, t) / dp`` of the texel
coordinates, exact from the homography and the camera's ``dq/dp``. The mip level is
``log2(max(minor, major / K))`` of ``J``'s column lengths and ``K`` taps are averaged along the
major column (anisotropic filtering as in GPU practice), blended trilinearly between levels,
so even the far, foreshortened ground is band-limited. Texture lookups are ``cv2.remap`` into the
mip atlases of `planar_vo.sim.textures` (float32; OpenCV quantises sample positions to 1/32
texel, i.e. at most 1/64 texel error).
"""

from __future__ import annotations

import functools
import logging
import warnings
from dataclasses import dataclass, field

import cv2
import numpy as np

from planar_vo.core.camera import CameraModel
from planar_vo.core.checks import as_array
from planar_vo.core.conventions import invert
from planar_vo.errors import InputError
from planar_vo.sim.textures import (
    COARSE_FROM_DETAIL,
    LAYER_WEIGHT,
    MACRO_AMPLITUDE,
    MACRO_WAVES,
    PAD,
    TextureBank,
    texture_bank,
)
from planar_vo.sim.world import StreetWorld

__all__ = ['RenderedFrame', 'render']

logger = logging.getLogger(__name__)

NEAR = 0.05                  # near clipping distance (m) along the optical axis
_TILE_PX = 16                # screen tiles used to bound each plane's pixels
_BATCH_TILES = 6             # planes covering at most this many tiles are z-buffered in a batch
_TAPS = 2                    # anisotropic taps along the footprint's major axis
_TAP_OFFSETS = tuple((k + 0.5) / _TAPS - 0.5 for k in range(_TAPS))   # in footprint lengths
_SKY = (195.0, 25.0)         # sky grey level at the horizon and its increase towards the zenith
_CHUNK_PIXELS = 8192         # pixels shaded per block (keeps the temporaries in cache)


@dataclass(frozen=True)
class RenderedFrame:
    """One rendered view.

    Attributes:
        image: grey image, uint8 ``(H, W)``.
        plane: index of the world plane seen at each pixel, int32 ``(H, W)``; -1 for sky (and
            for pixels outside a distorted camera's valid field).
        kind: what is seen, int8 ``(H, W)``: `GROUND_KIND`, `FACADE_KIND`, `OBSTACLE_KIND`,
            or -1 for sky.
        depth: depth ``z`` along the optical axis (m), float64 ``(H, W)``; inf for sky.
            Computed on first access (most users only need the image).
        T_odom_camera: the camera pose (4x4) the frame was rendered from.
        camera: the camera model.
    """

    image: np.ndarray
    plane: np.ndarray
    kind: np.ndarray
    T_odom_camera: np.ndarray
    camera: CameraModel
    # Inverse depth w = g . [q, 1] per world plane id (row -1: sky, g = 0), camera frame.
    _inverse_depth: np.ndarray = field(repr=False, compare=False)

    @functools.cached_property
    def depth(self) -> np.ndarray:
        """Depth along the optical axis (m), float64 ``(H, W)``; inf where no plane is seen."""
        rays = _rays(self.camera)
        g = self._inverse_depth[self.plane]
        with np.errstate(divide='ignore'):
            return 1.0 / (g[..., 0] * rays.qx + g[..., 1] * rays.qy + g[..., 2])


@dataclass(frozen=True)
class _Rays:
    """Per-camera constants: normalised ray coordinates of every pixel and screen tiles."""

    qx: np.ndarray             # (H, W) float64, 0 where invalid
    qy: np.ndarray
    qx32: np.ndarray           # float32 copies for the z-buffer pass
    qy32: np.ndarray
    valid: np.ndarray          # (H, W) bool: undistortion converged
    jq: tuple                  # dq/dp: four scalars (pinhole) or four (H, W) arrays
    tile_lo: np.ndarray        # (2, ny, nx) min qx, qy over each tile
    tile_hi: np.ndarray        # (2, ny, nx) max
    tile_qx: np.ndarray        # (ny * nx, TILE_PX^2) float32 qx of each tile's pixels (NaN: none)
    tile_qy: np.ndarray
    tile_pix: np.ndarray       # (ny * nx, TILE_PX^2) flat pixel index of each tile's pixels


@functools.lru_cache(maxsize=8)
def _rays(camera: CameraModel) -> _Rays:
    H, W = camera.height, camera.width
    v, u = np.mgrid[0:H, 0:W]
    p = np.stack([u.ravel(), v.ravel()], -1).astype(np.float64)
    q, Jq = camera.pixel_to_normalized(p)
    valid = np.isfinite(q).all(1) & np.isfinite(Jq).all((1, 2))
    q = np.where(valid[:, None], q, 0.0)
    qx, qy = q[:, 0].reshape(H, W), q[:, 1].reshape(H, W)
    valid = valid.reshape(H, W)
    if camera.is_distorted:
        Jq = np.where(valid.reshape(-1)[:, None, None], Jq, 0.0).reshape(H, W, 2, 2)
        jq = tuple(Jq[..., i, j].astype(np.float32) for i in (0, 1) for j in (0, 1))
    else:
        jq = tuple(float(x) for x in Jq[0].ravel())
    ny, nx = -(-H // _TILE_PX), -(-W // _TILE_PX)

    def by_tile(values: np.ndarray, fill) -> np.ndarray:
        """``(H, W)`` -> ``(tiles, TILE_PX^2)``, padding partial tiles with ``fill``."""
        padded = np.full((ny * _TILE_PX, nx * _TILE_PX), fill, dtype=values.dtype)
        padded[:H, :W] = values
        return np.ascontiguousarray(padded.reshape(ny, _TILE_PX, nx, _TILE_PX).swapaxes(1, 2)
                                    .reshape(ny * nx, _TILE_PX * _TILE_PX))

    qx32, qy32 = qx.astype(np.float32), qy.astype(np.float32)
    tile_qx = by_tile(np.where(valid, qx32, np.nan), np.nan)
    tile_qy = by_tile(np.where(valid, qy32, np.nan), np.nan)
    tile_pix = by_tile(np.arange(H * W).reshape(H, W), 0)
    with warnings.catch_warnings():                     # all-NaN tiles: no valid pixel
        warnings.simplefilter('ignore', RuntimeWarning)
        lo = np.stack([np.nanmin(t, axis=1) for t in (tile_qx, tile_qy)]).reshape(2, ny, nx)
        hi = np.stack([np.nanmax(t, axis=1) for t in (tile_qx, tile_qy)]).reshape(2, ny, nx)
    lo, hi = np.nan_to_num(lo, nan=np.inf), np.nan_to_num(hi, nan=-np.inf)
    return _Rays(qx, qy, qx32, qy32, valid, jq, lo, hi, tile_qx, tile_qy, tile_pix)


@dataclass(frozen=True)
class _Visible:
    """The planes that can be seen from a pose, in the camera frame."""

    index: np.ndarray          # (K,) world plane indices
    g: np.ndarray              # (K, 3, 3) rows g_a, g_b, g_n: [a w, b w, w] = g @ [q, 1]
    size: np.ndarray           # (K, 2)
    qlo: np.ndarray            # (K, 2) bounding box of the projection in q
    qhi: np.ndarray
    nearest: np.ndarray        # (K, 2) plane coordinates (a, b) of the point nearest the camera


def _visible(world: StreetWorld, T_odom_camera: np.ndarray) -> _Visible:
    """Planes not culled by facing (one-sided), range or the near plane; vectorised over planes."""
    T = invert(T_odom_camera)
    R, t = T[:3, :3], T[:3, 3]
    o = world.origin @ R.T + t
    u = world.axis_u @ R.T
    v = world.axis_v @ R.T
    n = np.cross(u, v)
    d = np.einsum('ij,ij->i', n, o)                    # plane: n . X = d; camera in front: d < 0
    keep = np.abs(d) > 1e-9
    keep &= ~(world.one_sided & (d >= 0.0))
    w, h = world.size[:, 0], world.size[:, 1]
    ua, vb = np.einsum('ij,ij->i', u, o), np.einsum('ij,ij->i', v, o)
    nearest = np.stack([np.clip(-ua, 0, w), np.clip(-vb, 0, h)], -1)
    closest = o + nearest[:, :1] * u + nearest[:, 1:] * v
    keep &= np.linalg.norm(closest, axis=1) <= world.max_range
    # Corners, clipped against z >= NEAR: the clipped polygon's vertices are the corners in front
    # and the edge crossings; their projections bound the plane's image.
    du, dv = u * w[:, None], v * h[:, None]
    P = np.stack([o, o + du, o + du + dv, o + dv], axis=1)
    Q = np.roll(P, -1, axis=1)
    zp, zq = P[..., 2] - NEAR, Q[..., 2] - NEAR
    cross = zp * zq < 0.0
    with np.errstate(divide='ignore', invalid='ignore'):
        X = P + (-zp / np.where(cross, zq - zp, 1.0))[..., None] * (Q - P)
    cand = np.concatenate([P, X], axis=1)
    ok = np.concatenate([zp >= 0.0, cross], axis=1)
    keep &= ok.any(axis=1)
    idx = np.flatnonzero(keep)
    cand, ok = cand[idx], ok[idx]
    z = np.where(ok, cand[..., 2], 1.0)
    qc = cand[..., :2] / z[..., None]
    qlo = np.where(ok[..., None], qc, np.inf).min(axis=1)
    qhi = np.where(ok[..., None], qc, -np.inf).max(axis=1)
    gn = n[idx] / d[idx, None]
    g = np.stack([u[idx] - ua[idx, None] * gn, v[idx] - vb[idx, None] * gn, gn], axis=1)
    return _Visible(idx, g, world.size[idx], qlo, qhi, nearest[idx])


def render(world: StreetWorld, camera: CameraModel, T_odom_camera: np.ndarray, *,
           psf_sigma: float = 0.5) -> RenderedFrame:
    """Render the view of a camera at pose ``T_odom_camera`` (4x4, optical frame in odom).

    Args:
        world: the scene.
        camera: intrinsics and distortion; the image is ``camera.height x camera.width``.
        T_odom_camera: camera pose, e.g. ``trajectory.camera_poses(mount)[k]``.
        psf_sigma: standard deviation (pixels) of a Gaussian lens blur applied to the image
            before quantisation, 0 for none. Like a real camera's optics it band-limits the image,
            so sub-pixel interpolation (optical flow, patch warps) stays consistent with the
            ground truth; it does not move anything.

    Returns:
        A `RenderedFrame` with the image, plane ids, kinds and depths.
    """
    T = as_array('T_odom_camera', T_odom_camera, (4, 4))
    if not isinstance(world, StreetWorld):
        raise InputError(f'world: expected a StreetWorld, got {type(world).__name__}')
    if not isinstance(camera, CameraModel):
        raise InputError(f'camera: expected a CameraModel, got {type(camera).__name__}')
    if not (np.isfinite(psf_sigma) and 0.0 <= psf_sigma <= 10.0):
        raise InputError(f'psf_sigma: expected a blur in [0, 10] pixels, got {psf_sigma!r}')
    rays = _rays(camera)
    vis = _visible(world, T)
    plane = _zbuffer(rays, vis)
    shade = _shade(world, rays, vis, plane, T)
    if psf_sigma > 0.0:
        shade = cv2.GaussianBlur(shade, (0, 0), psf_sigma, borderType=cv2.BORDER_REPLICATE)
    image = np.clip(np.rint(shade), 0, 255).astype(np.uint8)
    plane_id = np.append(vis.index, -1).astype(np.int32)[plane]
    kind = np.append(world.kind[vis.index], -1).astype(np.int8)[plane]
    g = np.zeros((len(world) + 1, 3))
    g[vis.index] = vis.g[:, 2]
    return RenderedFrame(image, plane_id, kind, T.copy(), camera, g)


def _zbuffer(rays: _Rays, vis: _Visible) -> np.ndarray:
    """Nearest plane per pixel: local index into ``vis`` (``K`` = none), intp ``(H, W)``."""
    H, W = rays.qx.shape
    K = len(vis.index)
    wbuf = np.zeros((H, W), np.float32)                # inverse depth; 0 = nothing (sky)
    plane = np.full((H, W), K, np.intp)
    # Screen tiles overlapping each plane's q-box bound the pixels to test.
    lo, hi = rays.tile_lo, rays.tile_hi
    hit = ((lo[0][None] <= vis.qhi[:, 0, None, None]) & (hi[0][None] >= vis.qlo[:, 0, None, None])
           & (lo[1][None] <= vis.qhi[:, 1, None, None])
           & (hi[1][None] >= vis.qlo[:, 1, None, None]))
    rows, cols = hit.any(axis=2), hit.any(axis=1)
    g = vis.g.astype(np.float32)
    size = vis.size.astype(np.float32)
    wmax = np.float32(1.0 / NEAR)
    tiles = rows.sum(axis=1) * cols.sum(axis=1)
    # Large planes one by one on their tile rectangle; then all small ones in one batch (their
    # per-plane call overhead would dominate).
    for k in np.flatnonzero(tiles > _BATCH_TILES):
        r = np.flatnonzero(rows[k])
        c = np.flatnonzero(cols[k])
        ys = slice(r[0] * _TILE_PX, (r[-1] + 1) * _TILE_PX)
        xs = slice(c[0] * _TILE_PX, (c[-1] + 1) * _TILE_PX)
        qx, qy = rays.qx32[ys, xs], rays.qy32[ys, xs]
        (a0, a1, a2), (b0, b1, b2), (n0, n1, n2) = g[k]
        iw = qx * n0 + qy * n1 + n2
        aw = qx * a0 + qy * a1 + a2
        bw = qx * b0 + qy * b1 + b2
        wb = wbuf[ys, xs]
        m = iw > wb
        m &= iw <= wmax
        m &= aw >= 0
        m &= bw >= 0
        m &= aw <= iw * size[k, 0]
        m &= bw <= iw * size[k, 1]
        np.copyto(wb, iw, where=m)
        plane[ys, xs][m] = k
    small = np.flatnonzero((tiles > 0) & (tiles <= _BATCH_TILES))
    if small.size:
        kk, ty, tx = np.nonzero(hit[small])
        k = small[kk]
        tile = ty * hit.shape[2] + tx
        qx, qy = rays.tile_qx[tile], rays.tile_qy[tile]                     # (P, TILE_PX^2)
        gk = g[k][..., None]
        iw = qx * gk[:, 2, 0] + qy * gk[:, 2, 1] + gk[:, 2, 2]
        aw = qx * gk[:, 0, 0] + qy * gk[:, 0, 1] + gk[:, 0, 2]
        bw = qx * gk[:, 1, 0] + qy * gk[:, 1, 1] + gk[:, 1, 2]
        m = ((iw <= wmax) & (aw >= 0) & (bw >= 0) & (aw <= iw * size[k, :1])
             & (bw <= iw * size[k, 1:]))
        i, j = np.nonzero(m)
        pix, w_new, k_new = rays.tile_pix[tile[i], j], iw[i, j], k[i]
        flat_w, flat_plane = wbuf.reshape(-1), plane.reshape(-1)
        keep = w_new > flat_w[pix]
        pix, w_new, k_new = pix[keep], w_new[keep], k_new[keep]
        # Nearest candidate per pixel: sort by pixel, then inverse depth; take each group's last.
        order = np.lexsort((w_new, pix))
        pix, w_new, k_new = pix[order], w_new[order], k_new[order]
        last = np.append(pix[1:] != pix[:-1], pix.size > 0)[:pix.size]
        flat_w[pix[last]] = w_new[last]
        flat_plane[pix[last]] = k_new[last]
    plane[~rays.valid] = K
    return plane


def _shade(world: StreetWorld, rays: _Rays, vis: _Visible, plane: np.ndarray,
           T_odom_camera: np.ndarray) -> np.ndarray:
    """Grey levels (float32, not yet rounded) of the pixels given their planes.

    Works on blocks of rows small enough to stay in the CPU cache: the per-pixel work is a long
    chain of element-wise operations, memory-bound on whole images.
    """
    bank = texture_bank()
    tile = float(bank.size[0])
    # Plane coordinates relative to the point nearest the camera, (a - a0, b - b0), and texture
    # offsets with whole tiles removed there (both layers are periodic with the tile): all
    # terms stay small, so float32 keeps the texel coordinates to ~1e-4 texel near the camera.
    g = vis.g.copy()
    g[:, :2] -= vis.nearest[:, :, None] * g[:, 2:3]
    g = np.concatenate([g, np.zeros((1, 3, 3))])                      # (K + 1, 3, 3)
    M = world.texture_map[vis.index].copy()
    M[:, :, 2] += (M[:, :, :2] @ vis.nearest[:, :, None])[..., 0]
    whole = tile * np.round(M[:, :, 2] / tile)
    M[:, :, 2] -= whole
    coarse = world.coarse_offset[vis.index] + whole @ COARSE_FROM_DETAIL.T
    coarse -= tile * np.floor(coarse / tile)
    # Macro waves are functions of the original detail coordinates d = d' + whole.
    phase = np.remainder(whole @ MACRO_WAVES.T, 2 * np.pi)          # (K, waves)
    # Detail texel coordinates: [s w, t w] = (M @ g) [q, 1].
    st = np.einsum('kij,kjl->ilk', np.concatenate([M, np.zeros((1, 2, 3))]), g)
    levels = np.arange(bank.levels + 1)
    tables = _Tables(
        gn=np.ascontiguousarray(g[:, 2].T).astype(np.float32),
        st=st.astype(np.float32),
        coarse=np.append(coarse, [[0.0, 0.0]], axis=0).T.astype(np.float32),
        phase=np.append(phase, np.zeros((1, len(MACRO_WAVES))), axis=0).T.astype(np.float32),
        row0=np.append(bank.y0[world.material[vis.index]] + PAD, PAD).astype(np.float32),
        gain=np.append(world.gain[vis.index], 0.0).astype(np.float32),
        bias=np.append(world.bias[vis.index], 0.0).astype(np.float32),
        sky=len(vis.index),
        scale=np.exp2(-levels).astype(np.float32),
        # Atlas column of level l: sum_{j<l} (T / 2^j + 2 PAD) = 2 T (1 - 2^-l) + 2 PAD l.
        column=(2 * tile * (1 - np.exp2(-levels)) + 2 * PAD * levels + PAD).astype(np.float32))
    H, W = plane.shape
    image = np.empty((H, W), np.float32)
    step = max(1, _CHUNK_PIXELS // W)
    for r0 in range(0, H, step):
        ys = slice(r0, min(H, r0 + step))
        jq = tuple(j[ys] if isinstance(j, np.ndarray) else j for j in rays.jq)
        image[ys] = _shade_rows(bank, tables, plane[ys], rays, ys, jq, T_odom_camera[2, :3])
    return image


@dataclass(frozen=True)
class _Tables:
    """Per-frame plane parameters indexed by local plane id (row ``sky`` = no plane)."""

    gn: np.ndarray                 # (3, K + 1): inverse depth w = gn . [q, 1]
    st: np.ndarray                 # (2, 3, K + 1): detail texels [s w, t w] = st . [q, 1]
    coarse: np.ndarray             # (2, K + 1): coarse-layer offsets
    phase: np.ndarray              # (waves, K + 1): macro-wave phases
    row0: np.ndarray               # (K + 1,) atlas row of the plane's material block
    gain: np.ndarray
    bias: np.ndarray
    sky: int
    scale: np.ndarray              # (levels + 1,) 2^-l
    column: np.ndarray             # (levels + 1,) atlas column of level l's tile (after PAD)


def _shade_rows(bank: TextureBank, tab: _Tables, pid: np.ndarray, rays: _Rays, ys: slice,
                jq: tuple, up_row: np.ndarray) -> np.ndarray:
    f32 = np.float32
    qx, qy = rays.qx32[ys], rays.qy32[ys]
    n0, n1 = tab.gn[0][pid], tab.gn[1][pid]
    w = n0 * qx + n1 * qy + tab.gn[2][pid]
    sky = pid == tab.sky
    w[sky] = 1.0
    iw = f32(1.0) / w
    j00, j01, j10, j11 = (j if isinstance(j, np.ndarray) else f32(j) for j in jq)
    # Detail texel coordinates and their q-gradients (plane-to-texel homography).
    coords, grads = [], []
    for i in range(2):
        c0, c1, c2 = tab.st[i, 0][pid], tab.st[i, 1][pid], tab.st[i, 2][pid]
        s = (c0 * qx + c1 * qy + c2) * iw
        grads.append(((c0 - s * n0) * iw, (c1 - s * n1) * iw))
        coords.append(s)
    (sqx, sqy), (tqx, tqy) = grads
    # Footprint columns d/dx and d/dy (detail texels per pixel) through dq/dp.
    if isinstance(j01, np.ndarray) or j01 or j10:
        sx, tx = sqx * j00 + sqy * j10, tqx * j00 + tqy * j10
        sy, ty = sqx * j01 + sqy * j11, tqx * j01 + tqy * j11
    else:
        sx, tx, sy, ty = sqx * j00, tqx * j00, sqy * j11, tqy * j11
    lx = sx * sx + tx * tx
    ly = sy * sy + ty * ty
    x_major = lx >= ly
    major2 = np.maximum(lx, ly)
    lam = f32(0.5) * np.log2(np.maximum(np.maximum(np.minimum(lx, ly),
                                                   major2 * f32(1.0 / _TAPS ** 2)), f32(1e-12)))
    ax = np.where(x_major, sx, sy)
    ay = np.where(x_major, tx, ty)
    # Macro waves, prefiltered: a Gaussian of the footprint's major length scales a wave of
    # wave number k by exp(-k^2 major^2 / 2).
    macro = np.zeros(pid.shape, f32)
    for (kx, ky), phase in zip(MACRO_WAVES.astype(f32), tab.phase):
        macro += np.cos(kx * coords[0] + ky * coords[1] + phase[pid]) * np.exp(
            f32(-0.5 * (kx * kx + ky * ky)) * major2)
    C = COARSE_FROM_DETAIL
    layers = (
        (coords[0], coords[1], lam, ax, ay),
        (f32(C[0, 0]) * coords[0] + f32(C[0, 1]) * coords[1] + tab.coarse[0][pid],
         f32(C[1, 0]) * coords[0] + f32(C[1, 1]) * coords[1] + tab.coarse[1][pid],
         lam + f32(np.log2(np.linalg.norm(C[0]))),
         f32(C[0, 0]) * ax + f32(C[0, 1]) * ay, f32(C[1, 0]) * ax + f32(C[1, 1]) * ay),
    )
    row0 = tab.row0[pid]
    tile = f32(bank.size[0])
    top = f32(bank.levels - 1 - 1e-3)
    total = np.zeros(pid.shape, f32)
    for atlas, weight, (u, v, lam, ax, ay) in zip(bank.atlases, LAYER_WEIGHT, layers):
        u = u - tile * np.floor(u / tile)
        v = v - tile * np.floor(v / tile)
        # Beyond the coarsest level the taps would leave the padded tile: drop them there.
        near = lam <= top
        lam = np.clip(lam, 0.0, top)
        level = lam.astype(np.intp)                      # floor: lam >= 0
        frac = lam - level.astype(f32)
        scale0 = tab.scale[level]
        ax = ax * scale0 * near
        ay = ay * scale0 * near
        col = tab.column[level]
        x = (u + f32(0.5)) * scale0 - f32(0.5) + col
        y = (v + f32(0.5)) * scale0 - f32(0.5) + row0
        k = f32(_TAP_OFFSETS[0])
        both = cv2.remap(atlas, x + k * ax, y + k * ay, cv2.INTER_LINEAR,
                         borderMode=cv2.BORDER_REPLICATE)
        for k in _TAP_OFFSETS[1:]:
            both += cv2.remap(atlas, x + f32(k) * ax, y + f32(k) * ay, cv2.INTER_LINEAR,
                              borderMode=cv2.BORDER_REPLICATE)
        v0, v1 = both[..., 0], both[..., 1]
        total += f32(weight / _TAPS) * (v0 + frac * (v1 - v0))
    shade = tab.bias[pid] + tab.gain[pid] * (total + f32(MACRO_AMPLITUDE) * macro)
    # Soft saturation instead of clipping: no flat (texture-less) patches where a dark blob meets
    # a dark surface; slope 1 at mid-grey.
    shade = f32(127.5) + f32(127.5) * np.tanh((shade - f32(127.5)) * f32(1 / 127.5))
    if sky.any():
        # Plain sky, brighter towards the zenith: elevation of the ray in odom.
        sqx, sqy = rays.qx[ys][sky], rays.qy[ys][sky]
        up = (up_row[0] * sqx + up_row[1] * sqy + up_row[2]) / np.sqrt(sqx ** 2 + sqy ** 2 + 1.0)
        shade[sky] = np.where(rays.valid[ys][sky], _SKY[0] + _SKY[1] * np.clip(up, 0.0, 1.0), 0.0)
    return shade
