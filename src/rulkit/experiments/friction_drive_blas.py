"""Limit the BLAS thread pools of numpy and scipy (helper of the friction-drive experiment).

The EKF's covariance prediction calls ``scipy.linalg.expm`` on small (B, 8, 8) stacks every
1 ms step; with OpenBLAS free to spawn one thread per core on a shared machine, each call took
~0.8 ms instead of ~0.06 ms (measured on the 2-core build host). ``threadpoolctl`` is not a
dependency, so this looks up the ``*openblas_set_num_threads*`` symbols of the OpenBLAS
libraries already loaded into the process (numpy's and scipy's wheels bundle their own) and
restores the previous counts on exit. Linux only (reads /proc/self/maps); elsewhere a no-op.
"""

from __future__ import annotations

import ctypes
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

_SET = ("scipy_openblas_set_num_threads64_", "scipy_openblas_set_num_threads",
        "openblas_set_num_threads64_", "openblas_set_num_threads")
_GET = ("scipy_openblas_get_num_threads64_", "scipy_openblas_get_num_threads",
        "openblas_get_num_threads64_", "openblas_get_num_threads")


def _openblas_handles() -> list[tuple[object, object]]:
    maps = Path("/proc/self/maps")
    if not maps.exists():
        return []
    paths = sorted({ln.split()[-1] for ln in maps.read_text().splitlines()
                    if "openblas" in ln.lower() and ln.split()[-1].startswith("/")})
    out = []
    for p in paths:
        try:
            lib = ctypes.CDLL(p)
        except OSError:
            continue
        setter = next((getattr(lib, n) for n in _SET if hasattr(lib, n)), None)
        getter = next((getattr(lib, n) for n in _GET if hasattr(lib, n)), None)
        if setter is not None and getter is not None:
            out.append((setter, getter))
    return out


@contextmanager
def blas_threads(n: int = 1) -> Iterator[None]:
    """Run the block with at most ``n`` OpenBLAS threads, restoring the previous counts."""
    import numpy  # noqa: F401  (make sure the libraries are loaded)
    import scipy.linalg  # noqa: F401

    handles = _openblas_handles()
    old = [int(g()) for _, g in handles]
    for s, _ in handles:
        s(int(n))
    try:
        yield
    finally:
        for (s, _), o in zip(handles, old, strict=True):
            s(o)
