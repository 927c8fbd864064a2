"""Fleet degradation models learned from histories (docs/fleet-models.md).

:mod:`.histories` reads and validates fleet histories (ages on a
:class:`~rulkit.fleet.time_axis.TimeAxis`) and :mod:`.checks` warns about implausible ones and
about fits; :mod:`.degradation` holds the linear, exponential and Paris-law random-effects models
with noise on their growth scale, :mod:`.hi_noise` the Paris law measured with additive or
multiplicative HI noise, :mod:`.onset` the same after a per-unit onset (filters and fits in
:mod:`.growth_filter`, :mod:`.filter_kernels`, :mod:`.growth_fit`), :mod:`.regression` and
:mod:`.similarity` the two baselines; :mod:`.candidates` names them all behind one interface,
:mod:`.selection` chooses among them on held-out units with the scores of :mod:`.scoring`,
:mod:`.evaluate` runs the leave-one-unit-out evaluation against naive baselines and
:mod:`.datasets` holds the real and synthetic fleets (with known truth) of docs/fleet-models.md.
"""
