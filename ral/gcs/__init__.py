"""Ground control station: a Python API (:mod:`ral.gcs.api`) and the ``cromat gcs`` command built on it."""
