"""Project-wide test settings."""

from __future__ import annotations

import pytest
from hypothesis import settings
from threadpoolctl import threadpool_limits

# Property tests run the same examples on every machine and every run (derandomize: a CI
# result does not depend on which random examples one run drew), with no per-example time
# limit (a loaded machine must not fail a correct test) and no example database on disk.
settings.register_profile("rulkit", deadline=None, derandomize=True, database=None)
settings.load_profile("rulkit")


@pytest.fixture(autouse=True, scope="session")
def _one_blas_thread():
    """One BLAS thread, as the CLI uses (see rulkit.cli.limit_blas_threads): the filters' small
    batched linear algebra is several times slower with BLAS threads on a 2-core machine."""
    with threadpool_limits(limits=1, user_api="blas"):
        yield
