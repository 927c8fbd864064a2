"""The component store: tracker state per component, history per acquisition.

- :mod:`.sqlite`: the SQLite store and its validated, all-or-nothing ingestion;
- :mod:`.postgres`: the PostgreSQL backend and :func:`~.postgres.open_store` (either backend);
- :mod:`.acquisitions`: acquisition batches read and validated, component ids;
- :mod:`.database_file`: the database as a file (read-only probing, meta settings, durability);
- :mod:`.prognosis`: one RUL per component and the alert rules over a batch, their columns and
  their replay;
- :mod:`.learned_state`: a learned degradation model and its per-component states in the store;
- :mod:`.status_view`: ``rulkit status`` read without pandas;
- :mod:`.cli`: ``rulkit track`` and ``rulkit status``.
"""
