"""Project-wide test settings."""

from __future__ import annotations

import pytest
from threadpoolctl import threadpool_limits


@pytest.fixture(autouse=True, scope="session")
def _one_blas_thread():
    """One BLAS thread, as the CLI uses (see rulkit.cli.limit_blas_threads): the filters' small
    batched linear algebra is several times slower with BLAS threads on a 2-core machine."""
    with threadpool_limits(limits=1, user_api="blas"):
        yield
