"""Physical models: one module per system, each a vectorised state-space model (see base.py)."""
