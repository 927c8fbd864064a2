"""Step 3: the remaining useful life under a lubrication fault (docs/systems/reaction-wheel.md
§5).

- :mod:`.forecast`: propagation of the step-2 posterior along a future temperature path to a
  loss threshold;
- :mod:`.study`: the Table 7 study, its metrics and figures.
"""
