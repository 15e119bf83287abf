"""Accuracy experiments of the minimal solvers on the paper's synthetic protocol.

Each trial (`planar_vo.sim.synthetic.paper_trial`) has 50 ACs sharing one motion. Per noise level:

- 1AC, 1AC+LS (constrained least-squares refinement) and 1ACf: every AC solved alone;
- 3PC and 2PC: 50 random minimal samples of the same points (2PC keeps the root nearer the
  truth, the usual way of scoring a solver with several roots);
- 5PC: OpenCV's five-point RANSAC on all 50 points (the pipeline users would otherwise pick).

Errors are absolute angle differences in degrees; the focal error is relative.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from planar_vo.bench.peers import estimate_5pc_opencv
from planar_vo.core import angle_difference, solve_1ac, solve_1acf, solve_2pc, solve_3pc
from planar_vo.errors import InputError
from planar_vo.sim.synthetic import paper_trial

__all__ = ['format_accuracy_table', 'solver_accuracy']

METHODS = ('1AC', '1AC+LS', '1ACf', '2PC', '3PC', '5PC (OpenCV)')


def _errors_deg(est: np.ndarray, truth) -> np.ndarray:
    return np.rad2deg(np.abs(angle_difference(est, truth)))


def solver_accuracy(sigmas: Sequence[float], *, trials: int = 200, seed: int = 0,
                    motion: str = 'general') -> list[dict]:
    """Per-method error statistics for each noise level.

    Returns:
        One dict per (sigma, method): ``sigma``, ``method``, ``alpha_median``, ``alpha_mean``,
        ``beta_median``, ``beta_mean`` (degrees), ``focal_median`` (relative, 1ACf only, else
        NaN) and ``valid`` (fraction of samples that gave a solution).
    """
    if trials < 1:
        raise InputError(f'trials: expected at least 1, got {trials}')
    if any(not (0.0 <= s < math.inf) for s in sigmas):
        raise InputError(f'sigmas: expected finite non-negative noise levels, got {list(sigmas)}')
    rng = np.random.default_rng(seed)
    rows = []
    for sigma in sigmas:
        acc: dict[str, dict[str, list]] = {m: {'a': [], 'b': [], 'f': []} for m in METHODS}
        for _ in range(trials):
            t = paper_trial(rng, sigma, motion=motion)
            q1, q2, A = t.normalized.p1, t.normalized.p2, t.normalized.A
            for name, refine in (('1AC', False), ('1AC+LS', True)):
                a, b = solve_1ac(q1, q2, A, refine=refine)
                acc[name]['a'].append(_errors_deg(a, t.alpha))
                acc[name]['b'].append(_errors_deg(b, t.beta))
            c1, c2 = t.centered
            a, b, f = solve_1acf(c1, c2, t.acs.A)
            acc['1ACf']['a'].append(_errors_deg(a, t.alpha))
            acc['1ACf']['b'].append(_errors_deg(b, t.beta))
            acc['1ACf']['f'].append(np.abs(f / t.focal - 1.0))
            n = len(q1)
            idx3 = np.argsort(rng.random((n, n)), axis=1)[:, :3]
            a, b = solve_3pc(q1[idx3], q2[idx3])
            acc['3PC']['a'].append(_errors_deg(a, t.alpha))
            acc['3PC']['b'].append(_errors_deg(b, t.beta))
            idx2 = idx3[:, :2]
            a, b = solve_2pc(q1[idx2], q2[idx2])
            ea, eb = _errors_deg(a, t.alpha), _errors_deg(b, t.beta)
            best = np.nanargmin(np.where(np.isnan(ea + eb), np.inf, ea + eb), axis=1)
            pick = np.arange(n), best
            acc['2PC']['a'].append(ea[pick])
            acc['2PC']['b'].append(eb[pick])
            est = estimate_5pc_opencv(q1, q2, threshold=max(sigma, 0.1) * 2.0 / t.focal)
            acc['5PC (OpenCV)']['a'].append(np.atleast_1d(_errors_deg(est.alpha, t.alpha)))
            acc['5PC (OpenCV)']['b'].append(np.atleast_1d(_errors_deg(est.beta, t.beta)))
        for name in METHODS:
            a = np.concatenate(acc[name]['a'])
            b = np.concatenate(acc[name]['b'])
            f = np.concatenate(acc[name]['f']) if acc[name]['f'] else np.array([np.nan])
            ok = np.isfinite(a) & np.isfinite(b)
            rows.append({
                'sigma': float(sigma), 'method': name,
                'alpha_median': float(np.median(a[ok])) if ok.any() else np.nan,
                'alpha_mean': float(np.mean(a[ok])) if ok.any() else np.nan,
                'beta_median': float(np.median(b[ok])) if ok.any() else np.nan,
                'beta_mean': float(np.mean(b[ok])) if ok.any() else np.nan,
                'focal_median': float(np.nanmedian(f)) if np.isfinite(f).any() else np.nan,
                'valid': float(ok.mean()),
            })
    return rows


def format_accuracy_table(rows: list[dict]) -> str:
    """Markdown table of `solver_accuracy` rows."""
    head = ('| sigma (px) | method | alpha median | alpha mean | beta median | beta mean '
            '| focal rel. median | solved |')
    lines = [head, '|' + '---|' * 8]
    for r in rows:
        focal = f'{r["focal_median"]:.2e}' if np.isfinite(r['focal_median']) else '-'
        lines.append(f'| {r["sigma"]:.2f} | {r["method"]} | {r["alpha_median"]:.2e} | '
                     f'{r["alpha_mean"]:.2e} | {r["beta_median"]:.2e} | {r["beta_mean"]:.2e} | '
                     f'{focal} | {100 * r["valid"]:.1f}% |')
    return '\n'.join(lines)
