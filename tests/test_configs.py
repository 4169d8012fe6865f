"""Every config composes, and every settings group of every experiment passes its checks."""

import pytest
from omegaconf import OmegaConf

from pipeline.assembly.build import build_safety, hole_sampling
from pipeline.benchmark import BenchmarkSettings
from pipeline.core.config import CONF_DIR, compose
from pipeline.core.errors import ConfigError
from pipeline.core.settings import parse
from pipeline.evaluate import EvalSettings
from pipeline.learning.models import ModelSettings
from pipeline.learning.training import MethodSettings, TrainSettings
from pipeline.tracking.runs import TrackingSettings

EXPERIMENTS = sorted(p.stem for p in (CONF_DIR / "experiment").glob("*.yaml"))


def check_all_groups(cfg) -> None:
    TrainSettings.from_config(cfg.train)
    ModelSettings.from_config(cfg.model)
    TrackingSettings.from_config(cfg.tracking)
    parse(EvalSettings, cfg.eval, "eval")
    parse(BenchmarkSettings, cfg.benchmark, "benchmark")
    for key in ("method", "baselines.sikm", "baselines.uikm"):
        MethodSettings.from_config(OmegaConf.select(cfg, key), key)
    build_safety(cfg.boom, cfg.tunnel, cfg.safety)
    hole_sampling(cfg.holes)


def test_there_are_experiments():
    assert {"quick", "paper", "sweep_lambda_mu", "sweep_safety"} <= set(EXPERIMENTS)


@pytest.mark.parametrize("experiment", [None, *EXPERIMENTS])
def test_every_experiment_composes_and_validates(experiment):
    cfg = compose([] if experiment is None else [f"experiment={experiment}"])
    OmegaConf.resolve(cfg)
    check_all_groups(cfg)


@pytest.mark.parametrize("boom", sorted(p.stem for p in (CONF_DIR / "boom").glob("*.yaml")))
def test_every_boom_config_loads(boom):
    from pipeline.assembly.build import load_boom

    assert load_boom(boom).n_joints >= 6


@pytest.mark.parametrize(("override", "pattern"), [
    ("train.steps=0", r"train.steps = 0: must be >= 1"),
    ("train.steps=-5", r"train.steps = -5: must be >= 1"),
    ("train.steps=nan", r"train.steps = nan: expected an integer"),
    ("train.eval_every=0", r"train.eval_every = 0: must be >= 1"),
    ("train.lr=0", r"train.lr = 0.0: must be > 0"),
    ("train.lr=abc", r"train.lr = 'abc': expected a number"),
    ("train.batch_size=0", r"train.batch_size = 0: must be >= 1"),
    ("model.activation=swish", r"model.activation = 'swish': expected one of"),
    ("tracking.enabled=maybe", r"tracking.enabled = 'maybe': expected true or false"),
    ("eval.timing_repeats=0", r"eval.timing_repeats = 0: must be >= 1"),
    ("benchmark.holes=-1", r"benchmark.holes = -1: must be >= 1"),
])
def test_bad_settings_are_named(override, pattern):
    with pytest.raises(ConfigError, match=pattern):
        check_all_groups(compose([override]))
