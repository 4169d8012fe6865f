"""Stage ``dashboard``: the MLflow UI on the project's store, and the URL that opens on the runs.

    python -m pipeline.dashboard                     # boom-ik's runs: http://127.0.0.1:5000/#/experiments/<id>/runs?...
    python -m pipeline.dashboard experiment=quick    # the quick study's experiment, boom-ik-quick
    python -m pipeline.dashboard tracking.ui_port=5001

It prints the URL of the experiment's runs table (MLflow 3.17 opens an experiment on its GenAI overview
otherwise) and serves until Ctrl-C. With ``tracking.uri`` an MLflow server it only prints that server's URL.
"""

from __future__ import annotations

import hydra
from omegaconf import DictConfig

from pipeline.core.signals import terminate_as_interrupt
from pipeline.tracking import dashboard
from pipeline.tracking.runs import TrackingSettings


@hydra.main(version_base="1.3", config_path="../conf", config_name="config")
def main(cfg: DictConfig) -> None:
    settings = TrackingSettings.from_config(cfg.tracking)
    proc, url = dashboard.start(settings)
    print(f"MLflow dashboard, experiment {settings.experiment} (its runs table):\n  {url}", flush=True)
    if proc is None:
        return
    try:
        with terminate_as_interrupt():  # Ctrl-C or SIGTERM: the UI (its own process group) goes too
            proc.wait()
    except KeyboardInterrupt:
        pass
    finally:
        dashboard.stop(proc)


if __name__ == "__main__":
    main()
