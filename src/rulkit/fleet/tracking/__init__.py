"""Tracking: condition indicators to a health index and the seed-004 tracker chain.

- :mod:`.health_index`: condition indicators (CIs) to a health index (HI);
- :mod:`.tracker_chain`: alpha-beta on HI, Paris-law RUL, alpha-beta-gamma on RUL, validity and
  alert levels, vectorised over components (docs/systems/embedded-rul.md);
- :mod:`.tracker_run`: the chain over many acquisitions per component (a batch's ingestion).
"""
