"""Which learned models the device runs, and the refusal of the others by name."""

import pytest

from rulkit.fleet.export.device_spec import ExportError
from rulkit.fleet.export.learned_device import EXPORTERS, learned_device
from rulkit.fleet.learned.degradation import KINDS, DegradationModel


@pytest.mark.parametrize("kind", KINDS)
def test_every_learned_kind_is_exported_or_refused_by_name(kind):
    if kind not in EXPORTERS:
        with pytest.raises(ExportError, match=repr(kind)):
            learned_device(type("Model", (), {"kind": kind})())  # type: ignore[arg-type]
        return
    model = DegradationModel(kind, -0.5 if kind == "paris" else 0.0, (-1.0, 0.5),
                             (0.1, 0.0, 0.1), 0.02, 0.01, 10.0)
    dev = learned_device(model)
    assert dev.kind == kind and dev.state_fields
    assert dev.constants["threshold"] == model.threshold


def test_unknown_learned_model_type_is_refused_by_name():
    class Similarity:
        kind = "similarity"

    with pytest.raises(ExportError, match="'similarity' has no C export"):
        learned_device(Similarity())  # type: ignore[arg-type]


def test_a_model_setting_the_template_does_not_implement_is_refused():
    import dataclasses

    @dataclasses.dataclass(frozen=True)
    class Extended(DegradationModel):
        noise_scale: str = "transformed"

    base = dict(kind="linear", shape=0.0, mean=(0.1, 0.5), cov=(0.1, 0.0, 0.1),
                noise_sd=0.02, walk_sd=0.0, time_scale=10.0)
    assert learned_device(Extended(**base)).kind == "linear"  # default: the known model
    with pytest.raises(ExportError, match="noise_scale = 'hi' has no C export"):
        learned_device(Extended(**base, noise_scale="hi"))
