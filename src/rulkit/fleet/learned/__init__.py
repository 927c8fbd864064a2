"""Fleet degradation models learned from histories (docs/fleet-models.md).

:mod:`.histories` reads and validates fleet histories, :mod:`.degradation` holds the linear,
exponential and Paris-law random-effects models (learned prior, conjugate online update, RUL
distribution), :mod:`.evaluate` the leave-one-unit-out evaluation against naive baselines,
:mod:`.datasets` the real and synthetic fleets used in docs/fleet-models.md.
"""
