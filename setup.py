"""What goes into the wheel besides ``pipeline``: paths that pyproject.toml's package settings cannot map.

* ``conf/`` (the Hydra configs and the tunnel profiles) as ``pipeline/_conf/``, so the stages compose from
  the package when there is no checkout (``pipeline.core.config.config_dir``). The top-level ``conf/`` stays
  where DVC, Hydra overrides and users of the repository expect it; the wheel carries a copy of its files.
* ``scripts/round_check/`` as the top-level package ``round_check`` (the independent round checker:
  ``python -m round_check``, ``boom-ik-check-round``); ``scripts/check_round.py`` stays the checkout's command.

Everything else (name, dependencies, commands) is in pyproject.toml.
"""

from pathlib import Path

from setuptools import find_packages, setup

# conf/ and each folder in it, as data packages (listed, so setuptools knows every folder it copies)
CONF = ["pipeline._conf", *sorted(".".join(("pipeline._conf", *d.relative_to("conf").parts))
                                  for d in Path("conf").rglob("*") if d.is_dir() and d.name != "__pycache__")]

setup(
    packages=[*find_packages(include=["pipeline", "pipeline.*"]), *CONF, "round_check"],
    package_dir={"pipeline._conf": "conf", "round_check": "scripts/round_check"},
    package_data={name: ["*.yaml", "*.csv"] for name in CONF},
)
