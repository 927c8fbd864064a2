"""The prognosis chain of one component type as dependency-free C for the device
(docs/rul-on-the-device.md): :mod:`~rulkit.fleet.export.device_spec` (what is exported),
:mod:`~rulkit.fleet.export.learned_device` (which learned models, and what a new one needs),
:mod:`~rulkit.fleet.export.generator` (templates to C), :mod:`~rulkit.fleet.export.fixed_point`
(Q formats), :mod:`~rulkit.fleet.export.verify` (compile and compare with Python).
"""
