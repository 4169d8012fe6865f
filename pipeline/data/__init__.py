"""The study's hole data: sampling, hole sets and tables on disk, validation."""
