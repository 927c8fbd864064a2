"""Fixtures of the C export tests: the system C compiler (a failure, not a skip, under
RULKIT_REQUIRE_INTEGRATION=1)."""

import pytest

from rulkit.fleet.export.verify import compiler


@pytest.fixture
def cc(need):
    found = compiler()
    need(None if found else "no C compiler (cc, gcc or clang) on the PATH")
    return found
