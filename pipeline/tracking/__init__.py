"""MLflow: the store, one run per stage, sweeps as parent runs."""
