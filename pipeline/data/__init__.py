"""Hole sets and tables on disk: sampling, validation, drill plans."""
