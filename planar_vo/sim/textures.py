"""Procedural, seeded, tileable textures and their mip-map atlases (no external images).

Each material (ground, facade, vehicle) has two layers: a DETAIL tile (about 1 cm per texel) and a
COARSE tile (about 12 cm per texel), both periodic ``T x T`` with zero mean and unit standard
deviation. A surface's brightness is a weighted sum of both layers placed with per-surface
rotations and offsets; the two periods (about 10 m and 120 m) are incommensurate and rotated
differently, so the sum does not repeat anywhere a camera looks, while each layer supplies
texture at the scales where the other is too fine (blurred away by the mip-map) or too coarse.

Content: multi-octave ``1/f^beta`` noise synthesised in the Fourier domain (periodic by
construction), plus blobs, lines and rectangles drawn with wrap-around.

Anti-aliasing: each tile's mip pyramid (2x2 box averages, which keep a power-of-two tile
periodic) is packed into one two-channel float32 atlas per layer (level ``l`` and level ``l + 1``
resampled on level ``l``'s grid), every level padded by wrapped copies, so a single ``cv2.remap``
samples any material at two adjacent levels with wrap-around bilinear interpolation.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import cv2
import numpy as np

__all__ = [
    'COARSE_FROM_DETAIL',
    'DETAIL_TEXEL',
    'FACADE',
    'GROUND',
    'LAYERS',
    'LAYER_WEIGHT',
    'MACRO_AMPLITUDE',
    'MACRO_WAVES',
    'MATERIALS',
    'TextureBank',
    'VEHICLE',
    'texture_bank',
]

GROUND, FACADE, VEHICLE = 0, 1, 2
MATERIALS = ('ground', 'facade', 'vehicle')
LAYERS = ('detail', 'coarse')
TILE = 1024
# Level-0 texel size of the detail layer (m). The coarse layer's texel coordinates are a fixed
# similarity of the detail layer's, ``c = COARSE_FROM_DETAIL @ d + offset``: 11.7x larger texels
# (period about 120 m against 10 m) rotated by 0.61 rad, so the two lattices never line up and the
# sum does not repeat; the renderer reuses the detail footprint for the coarse layer.
DETAIL_TEXEL = 0.01
_COARSE_RATIO, _COARSE_ANGLE = 1.0 / 11.7, 0.61
COARSE_FROM_DETAIL = _COARSE_RATIO * np.array([[np.cos(_COARSE_ANGLE), -np.sin(_COARSE_ANGLE)],
                                               [np.sin(_COARSE_ANGLE), np.cos(_COARSE_ANGLE)]])
# Weight of each layer (grey levels per unit standard deviation) in a surface's brightness.
LAYER_WEIGHT = (24.0, 26.0)
# Macro layer: smooth brightness waves over the detail texel coordinates (periods of about 37,
# 83 and 191 m, incommensurate with the coarse tile's ~120 m), evaluated analytically and
# attenuated by the pixel footprint (a Gaussian prefilter), so even the far field where only the
# coarse layer survives never repeats.
_MACRO_PERIODS = np.array([3700.0, 8300.0, 19100.0])          # detail texels
_MACRO_ANGLES = np.array([0.3, 1.9, 4.1])
MACRO_WAVES = (2 * np.pi / _MACRO_PERIODS)[:, None] * np.stack(
    [np.cos(_MACRO_ANGLES), np.sin(_MACRO_ANGLES)], -1)        # (waves, 2) rad per texel
MACRO_AMPLITUDE = 9.0                                          # grey levels per wave
PAD = 4          # wrapped border per level: centre in [-0.5, T), taps +-1 texel, bilinear +1

# Per material and layer: noise spectral exponent (amplitude ~ 1/f^beta), noise weight, and the
# number of blobs, lines and rectangles drawn on top (each with a random grey level).
_RECIPES = {
    (GROUND, 0): dict(beta=0.55, noise=1.0, blobs=600, blob_size=(2, 10), lines=60, rects=0),
    (GROUND, 1): dict(beta=1.0, noise=0.8, blobs=250, blob_size=(6, 60), lines=80, rects=40),
    (FACADE, 0): dict(beta=0.75, noise=1.0, blobs=300, blob_size=(2, 12), lines=40, rects=300),
    (FACADE, 1): dict(beta=1.1, noise=0.6, blobs=120, blob_size=(6, 40), lines=60, rects=500),
    (VEHICLE, 0): dict(beta=0.7, noise=1.0, blobs=400, blob_size=(2, 12), lines=30, rects=60),
    (VEHICLE, 1): dict(beta=1.2, noise=0.7, blobs=150, blob_size=(8, 50), lines=40, rects=60),
}


@dataclass(frozen=True)
class TextureBank:
    """Mip-map atlases of every material, one per layer.

    Attributes:
        atlases: per layer, float32 ``(rows, cols, 2)``; material ``m``'s level ``l`` occupies
            rows ``y0[m] : y0[m] + size[l] + 2 PAD`` and columns ``x0[l] : x0[l] + size[l] +
            2 PAD``. Channel 0 is level ``l``; channel 1 is level ``l + 1`` resampled (bilinear,
            wrapped) at level ``l``'s texel centres, so one lookup returns both levels that a
            trilinear blend needs.
        x0: column of each level's padded block, shape ``(levels,)``.
        y0: row of each material's padded block, shape ``(materials,)``.
        size: tile size of each level (``TILE >> l``), shape ``(levels,)``.
    """

    atlases: tuple[np.ndarray, ...]
    x0: np.ndarray
    y0: np.ndarray
    size: np.ndarray

    @property
    def levels(self) -> int:
        return int(self.size.shape[0])


def _wrapped(draw, canvas: np.ndarray, size: int) -> None:
    """Call ``draw(canvas, dx, dy)`` at the nine offsets that make shapes wrap around the tile."""
    for dy in (-size, 0, size):
        for dx in (-size, 0, size):
            draw(canvas, dx, dy)


def _noise(rng: np.random.Generator, size: int, beta: float) -> np.ndarray:
    spectrum = np.fft.rfft2(rng.standard_normal((size, size)))
    f = np.hypot(np.fft.fftfreq(size)[:, None], np.fft.rfftfreq(size)[None, :])
    f[0, 0] = np.inf                                     # zero mean
    img = np.fft.irfft2(spectrum * f ** -beta, s=(size, size))
    return img / img.std()


def _tile(rng: np.random.Generator, size: int, beta: float, noise: float, blobs: int,
          blob_size: tuple[int, int], lines: int, rects: int) -> np.ndarray:
    """One periodic ``size x size`` float32 tile with zero mean and unit standard deviation."""
    img = (noise * _noise(rng, size, beta)).astype(np.float32)
    shapes = np.zeros((size, size), np.float32)
    for _ in range(blobs):
        c = rng.uniform(0, size, 2).astype(int)
        axes = rng.integers(*blob_size, 2)
        angle, value = rng.uniform(0, 180), rng.normal(0, 1.5)
        _wrapped(lambda im, dx, dy: cv2.ellipse(
            im, (int(c[0] + dx), int(c[1] + dy)), (int(axes[0]), int(axes[1])), angle, 0, 360,
            value, -1, cv2.LINE_AA), shapes, size)
    for _ in range(lines):
        a = rng.uniform(0, size, 2)
        b = a + rng.normal(0, size / 8, 2)
        thickness, value = int(rng.integers(1, 5)), rng.normal(0, 2.0)
        _wrapped(lambda im, dx, dy: cv2.line(
            im, (int(a[0] + dx), int(a[1] + dy)), (int(b[0] + dx), int(b[1] + dy)), value,
            thickness, cv2.LINE_AA), shapes, size)
    for _ in range(rects):
        a = rng.uniform(0, size, 2)
        wh = rng.uniform(4, 40, 2)
        value, frame = rng.normal(0, 1.5), rng.normal(0, 1.5)
        _wrapped(lambda im, dx, dy: (
            cv2.rectangle(im, (int(a[0] + dx), int(a[1] + dy)),
                          (int(a[0] + wh[0] + dx), int(a[1] + wh[1] + dy)), value, -1),
            cv2.rectangle(im, (int(a[0] + dx), int(a[1] + dy)),
                          (int(a[0] + wh[0] + dx), int(a[1] + wh[1] + dy)), frame, 2)), shapes,
                 size)
    img += shapes
    img = (img - img.mean()) / img.std()
    # Squash the rare extremes (stacked dark or bright shapes) so that no surface saturates.
    img = 2.0 * np.tanh(img / 2.0)
    img -= img.mean()
    return img / img.std()


def _pyramid(tile: np.ndarray) -> list[np.ndarray]:
    levels = [tile]
    while levels[-1].shape[0] > 1:
        prev = levels[-1]
        # 2x2 box average: exact prefilter for a power-of-two periodic tile.
        levels.append(0.25 * (prev[0::2, 0::2] + prev[1::2, 0::2] + prev[0::2, 1::2]
                              + prev[1::2, 1::2]))
    return levels


def _upsample(level: np.ndarray) -> np.ndarray:
    """A periodic level sampled bilinearly at the texel centres of the next finer level.

    Finer texel ``2 i + a`` has coarse coordinate ``i + a / 2 - 1/4``: weights 3/4 and 1/4.
    """
    def along(img: np.ndarray, axis: int) -> np.ndarray:
        prev, nxt = np.roll(img, 1, axis), np.roll(img, -1, axis)
        out = np.stack([0.75 * img + 0.25 * prev, 0.75 * img + 0.25 * nxt], axis=axis + 1)
        shape = list(img.shape)
        shape[axis] *= 2
        return out.reshape(shape)
    return along(along(level, 0), 1)


@functools.lru_cache(maxsize=1)
def texture_bank() -> TextureBank:
    """The textures of every material and layer (built once per process, ~0.6 s, ~100 MB).

    Fixed content (seeded internally): worlds differ by where and how they place it.
    """
    rng = np.random.default_rng(0x7E87)
    pyramids = {key: _pyramid(_tile(rng, TILE, **recipe)) for key, recipe in _RECIPES.items()}
    size = np.array([p.shape[0] for p in pyramids[(GROUND, 0)]])
    widths = size + 2 * PAD
    x0 = np.concatenate([[0], np.cumsum(widths)[:-1]])
    y0 = np.arange(len(MATERIALS)) * (TILE + 2 * PAD)
    atlases = []
    for layer in range(len(LAYERS)):
        atlas = np.zeros((len(MATERIALS) * (TILE + 2 * PAD), int(widths.sum()), 2), np.float32)
        for m in range(len(MATERIALS)):
            pyramid = pyramids[(m, layer)]
            for lvl, img in enumerate(pyramid):
                coarser = _upsample(pyramid[lvl + 1]) if lvl + 1 < len(pyramid) else img
                block = np.pad(np.dstack([img, coarser]), ((PAD, PAD), (PAD, PAD), (0, 0)),
                               mode='wrap')
                atlas[y0[m]:y0[m] + block.shape[0], x0[lvl]:x0[lvl] + block.shape[1]] = block
        atlas.setflags(write=False)
        atlases.append(atlas)
    return TextureBank(tuple(atlases), x0, y0, size)
