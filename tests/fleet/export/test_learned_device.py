"""Which learned models the device runs, and the refusal of the others by name."""

import pytest

from rulkit.fleet.export.device_spec import ExportError
from rulkit.fleet.export.learned_device import EXPORTERS, learned_device
from rulkit.fleet.learned.degradation import KINDS, DegradationModel


@pytest.mark.parametrize("kind", KINDS)
def test_every_learned_kind_is_exported_or_refused_by_name(kind):
    model = DegradationModel(kind, -0.5 if kind == "paris" else 0.0, (-1.0, 0.5),
                             (0.1, 0.0, 0.1), 0.02, 0.01, 10.0)
    if kind in EXPORTERS:
        dev = learned_device(model)
        assert dev.kind == kind and dev.state_fields
        assert dev.constants["threshold"] == model.threshold
    else:
        with pytest.raises(ExportError, match=repr(kind)):
            learned_device(model)


def test_unknown_learned_model_type_is_refused_by_name():
    class Similarity:
        kind = "similarity"

    with pytest.raises(ExportError, match="'similarity' has no C export"):
        learned_device(Similarity())  # type: ignore[arg-type]
