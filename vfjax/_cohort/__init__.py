"""Cohorts: every recording of a folder or manifest fitted and diagnosed in one resumable
job, in this process or on a Dask cluster (`vfjax.cohort`).

- ``_inputs``: the recordings of a folder or manifest (`CohortEntry`), how each is read, and
  the content key of its results;
- ``_options``: `CohortOptions`;
- ``_store``: the output folder, one whole folder per recording;
- ``_work``: reading, the batched first fits, the diagnoses and each recording's row;
- ``_table`` and ``_report``: the cohort table (CSV, Parquet) and report;
- ``_run``: `cohort`, serial or on Dask workers.
"""

from ._inputs import CohortEntry, find_entries, read_manifest
from ._options import CohortOptions
from ._run import cohort

__all__ = ["CohortEntry", "CohortOptions", "cohort", "find_entries", "read_manifest"]
