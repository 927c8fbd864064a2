"""The spec of an export from a database or a configuration file."""

import pytest

from rulkit.fleet.export.device_spec import ExportError, spec_from_database, spec_from_file
from rulkit.fleet.store.sqlite import ComponentStore
from rulkit.fleet.tracking.tracker_chain import TrackerConfig
from rulkit.machine_file import MachineFileError


def test_from_a_database_reads_what_the_store_holds(tmp_path):
    cfg = TrackerConfig.safe(dt=2.0, hi_sigma=0.03)
    ComponentStore(tmp_path / "f.db", config=cfg).close()
    spec = spec_from_database(tmp_path / "f.db")
    assert spec.config == cfg and spec.hi_model is None and spec.learned is None
    assert spec.name == "f"
    with pytest.raises(ExportError, match="no such database"):
        spec_from_database(tmp_path / "missing.db")
    (tmp_path / "foreign.db").write_bytes(b"not a database")
    with pytest.raises(ExportError, match="not an SQLite database"):
        spec_from_database(tmp_path / "foreign.db")


def test_from_a_file_fills_defaults_and_names_bad_values(tmp_path):
    f = tmp_path / "c.toml"
    f.write_text("[tracker]\nload_exponent = 1.0\nvalid_drul_low = -3.0\n")
    spec = spec_from_file(f)
    assert spec.config.load_exponent == 1.0 and spec.config.valid_drul == (-3.0, 0.0)
    assert spec.config.dt == TrackerConfig().dt and spec.learned is None
    f.write_text("[tracker]\ndt = -1.0\n")
    with pytest.raises(MachineFileError, match=r"\[tracker\] dt = -1.0"):
        spec_from_file(f)
    f.write_text('[learned]\nkind = "paris"\ncov_aa = 1.0\ncov_ab = 5.0\ncov_bb = 1.0\n')
    with pytest.raises(MachineFileError, match=r"\[learned\] .*not a covariance"):
        spec_from_file(f)
