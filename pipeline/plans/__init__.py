"""The product side: drill plans (model, CSV, IREDES, the demo-face designer) and solution tables."""
