"""Group commit of concurrent batches on both backends: batches that arrive while another is
written share one transaction and one commit, each still all or nothing. Before, every batch
paid its own commit."""


import pandas as pd

from .conftest import one_group


def test_concurrent_batches_share_one_commit(sdb):
    batches = [pd.DataFrame({"component": [f"g{k}-{i}" for i in range(20)], "time": 1.0,
                             "hi": 0.3}) for k in range(8)]
    out = [None] * 8
    with one_group(sdb, [lambda k=k: out.__setitem__(k, sdb.ingest(batches[k], f"b{k}"))
                         for k in range(8)]):
        pass  # one transaction for the eight
    assert [o["ingested"] for o in out] == [20] * 8
    assert sdb.components(limit=1, offset=0)[0] == 160
    # a batch that conflicts with the stored rows is refused alone, in the same group
    bad = batches[0].assign(time=0.5)
    res = {}
    with one_group(sdb, [lambda: res.setdefault("ok", sdb.ingest(batches[1].assign(time=2.0),
                                                                  "ok")),
                         lambda: res.setdefault("bad", _catch(sdb, bad))]):
        pass
    assert res["ok"]["ingested"] == 20 and "before the component's last stored" in res["bad"]
    assert sdb.components(limit=1, offset=0)[0] == 160


def _catch(sdb, df):
    try:
        sdb.ingest(df, "bad")
    except ValueError as err:
        return str(err)
    return "accepted"


def test_a_failed_group_stores_nothing_and_the_next_group_commits(sdb, monkeypatch):
    from rulkit.fleet.store.sqlite import ComponentStore

    df = pd.DataFrame({"component": ["f0", "f1"], "time": 1.0, "hi": 0.3})
    sdb.ingest(df, "first")  # the group commits' own connection is open
    writer = sdb._writer

    def broken(self, *a, **k):
        raise OSError("disk gone")  # neither a refusal nor a conflict: the group fails

    with monkeypatch.context() as m:
        m.setattr(ComponentStore, "_insert_ingest", broken)
        m.setattr(type(writer), "_insert_ingest", broken)
        try:
            sdb.ingest(df.assign(time=2.0), "lost")
        except OSError as err:
            assert "disk gone" in str(err)
        else:
            raise AssertionError("the failed group was acknowledged")
    assert sdb.component("f0")["n"] == 1  # nothing of the failed group
    assert sdb.ingest(df.assign(time=2.0), "again")["ingested"] == 2
    assert sdb.component("f0")["n"] == 2
