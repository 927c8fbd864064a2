"""Step 2: the parameters b and beta0 of the lubricant-loss law (docs/systems/reaction-wheel.md
§4).

- :mod:`.quadrature`: the window sums S_k(b) by Gauss quadrature;
- :mod:`.trackers`: the one-step and two-step particle filters and the Rao-Blackwellised PF;
- :mod:`.shortcut`: the T^ error process that stands in for step 1 over months;
- :mod:`.study`: the Table 6 study (error statistics, shortcut validation, sensitivity).
"""
