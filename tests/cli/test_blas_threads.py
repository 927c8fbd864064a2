"""``--blas-threads`` caps BLAS whether numpy is loaded before or after the option is read
(most commands import numpy only when they run; threadpoolctl alone saw no BLAS then)."""

from __future__ import annotations

import subprocess
import sys

import pytest

_SCRIPT = """
import sys
{before}
from rulkit.cli import limit_blas_threads
limit_blas_threads(1)
import numpy
from threadpoolctl import threadpool_info
print(max(i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"))
"""


@pytest.mark.parametrize("before", ["", "import numpy"])
def test_blas_threads_capped_before_and_after_numpy_loads(before: str) -> None:
    out = subprocess.run([sys.executable, "-c", _SCRIPT.format(before=before)], check=True,
                         capture_output=True, text=True, timeout=120,
                         env={"PATH": "/usr/bin:/bin", "OPENBLAS_NUM_THREADS": "4"})
    assert out.stdout.strip() == "1", out.stdout
