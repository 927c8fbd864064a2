"""The page cache's rules (src/rulkit/fleet/service/page_cache.py): a page is served again
only at the version it was read after and within its clock window; a newer version empties
the cache, a page of an older one is never kept."""

from rulkit.fleet.service.page_cache import PageCache


def test_pages_are_served_at_their_version_and_in_their_window():
    cache = PageCache()
    assert cache.get("a", 5, 100.0) is None  # first sight of version 5
    cache.put("a", 5, 100.0, 200.0, b"A")
    assert cache.get("a", 5, 100.0) == b"A"
    assert cache.get("a", 5, 199.9) == b"A"
    assert cache.get("a", 5, 200.0) is None  # the clock reached the next stale component
    assert cache.get("a", 5, 99.0) is None  # a clock set back
    assert cache.get("b", 5, 150.0) is None  # another query
    assert cache.hits == 2
    assert cache.get("a", 6, 150.0) is None  # a commit since: everything is dropped
    assert cache.get("a", 6, 150.0) is None
    cache.put("a", 5, 150.0, 300.0, b"old")  # read after version 5 only: maybe stale
    assert cache.get("a", 6, 150.0) is None
    assert cache.get("a", 4, 150.0) is None  # a request that saw an older version
    cache.put("a", 6, 150.0, 150.0, b"X")  # an empty window is not kept
    assert cache.get("a", 6, 150.0) is None
    cache.put("a", 6, 150.0, float("inf"), b"B")
    assert cache.get("a", 6, 1e12) == b"B"


def test_the_cache_holds_at_most_max_bytes():
    cache = PageCache(max_bytes=10)
    cache.get("k", 1, 0.0)
    cache.put("a", 1, 0.0, 1.0, b"123456")
    cache.put("b", 1, 0.0, 1.0, b"123456")  # over the bound: the older pages go
    assert cache.get("a", 1, 0.5) is None and cache.get("b", 1, 0.5) == b"123456"
    cache.put("b", 1, 0.0, 1.0, b"1234567890")  # replacing a page counts it once
    assert cache.get("b", 1, 0.5) == b"1234567890"
