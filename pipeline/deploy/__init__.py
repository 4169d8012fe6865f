"""Deployment: the trained network's export formats (``formats``), the packaged export with its manifest
(``package``: staged, published only after the read-back check) and the latency harness (``latency``)."""
