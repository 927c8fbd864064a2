"""The fleet service: ``rulkit serve`` (HTTP API + dashboard over the component store).

* :mod:`.db`: the service's tables (API tokens, alerts with acknowledgements) and the
  idempotent batch ingestion (duplicates, conflicts) on either backend;
* :mod:`.fleet_view`: what the API and dashboard read (one RUL per component, counts, the HI
  forecast);
* :mod:`.app`: the FastAPI application (``/api/v1``, ``/healthz``, the dashboard at ``/``),
  its routes by group in :mod:`.routes_service`, :mod:`.routes_acquisitions`,
  :mod:`.routes_components` and :mod:`.routes_alerts`, their dependencies in :mod:`.auth` and
  their responses in :mod:`.responses`;
* :mod:`.cli`: ``rulkit serve`` and ``rulkit token create|revoke|list``;
* :mod:`.pgtemp`: a throwaway PostgreSQL server for tests and benchmarks.

See docs/service.md. FastAPI, uvicorn and psycopg come with the ``service`` extra.
"""
