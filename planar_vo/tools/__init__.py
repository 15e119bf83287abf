"""Orchestration over the pipeline and the I/O: offline replay of bags (`replay`), rendered drives
recorded as bags (`record`), the demo (`demo`) and trajectory evaluation (`evaluation`).

Nothing here is imported by the runtime (the pipeline and the node)."""
