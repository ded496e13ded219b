"""The fleet layer: many passes of many trains in one track condition database (DuckDB).

``passes`` inverts one bag (a Dask task), ``align`` puts a pass on its line's chainage,
``fuse`` merges the aligned passes into one profile per line, ``defects`` and ``trend`` follow
each defect over time, ``db`` holds the schema, ``ingest`` runs a batch on Dask, ``query`` and
``report`` read the database back (docs/fleet.md).
"""
