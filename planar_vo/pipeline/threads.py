"""BLAS thread limits for the processes that run the pipeline (the node, the ``planar_vo`` CLI).

numpy's OpenBLAS starts one worker thread per core, and its idle workers busy-wait for the next
call: the pipeline's matrices are small (thousands of ACs, 2x2 to 6x6 blocks), so the workers
bring no speed-up, but a node doing 25 ms of work per 100 ms frame burned a whole core waiting.
One BLAS thread removes that waste; OpenCV's own thread pool (the front-end's flow) is not
affected.

`threadpoolctl` changes the limit of the BLAS library numpy has already loaded, so this works
wherever it is called (no environment variable has to be set before numpy is imported). An
explicit ``OPENBLAS_NUM_THREADS``, ``MKL_NUM_THREADS`` or ``OMP_NUM_THREADS`` in the
environment is the user's choice and is kept.
"""

from __future__ import annotations

import logging
import os

__all__ = ['BLAS_THREAD_VARIABLES', 'limit_blas_threads']

log = logging.getLogger(__name__)

# The variables BLAS libraries read at load time; any of them set means the user decided.
BLAS_THREAD_VARIABLES = ('OPENBLAS_NUM_THREADS', 'MKL_NUM_THREADS', 'OMP_NUM_THREADS',
                         'BLIS_NUM_THREADS')


def limit_blas_threads(threads: int = 1) -> int | None:
    """Limit the BLAS libraries loaded in this process to ``threads`` threads (process-wide,
    until exit), unless the environment sets a thread count.

    Returns the limit applied, or None when the environment's choice was kept.
    """
    if any(os.environ.get(name) for name in BLAS_THREAD_VARIABLES):
        log.debug('BLAS threads left as the environment sets them')
        return None
    import numpy  # noqa: F401 - load numpy's BLAS first, so that there is something to limit
    from threadpoolctl import threadpool_limits

    threadpool_limits(limits=int(threads), user_api='blas')
    log.debug('BLAS limited to %d thread(s)', threads)
    return int(threads)
