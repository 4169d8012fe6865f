"""The wheel works without a checkout: it carries conf/ (as ``pipeline/_conf/``) and the round checker (the
top-level ``round_check``) and both commands; outside a checkout the configs are the packaged copy and
relative paths are the working directory's; ``boom-ik <stage>`` is ``python -m pipeline.<stage>``.

The wheel is built from a copy of the files it is made of (``pip wheel --no-build-isolation``: the
installed setuptools, nothing downloaded, where it is new enough), so the checkout is left as it is.
``.ci/run`` also installs it into a fresh environment and runs stages from an empty folder."""

import importlib
import importlib.metadata
import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest
from omegaconf import OmegaConf

from pipeline.core import config
from pipeline.core.config import PROJECT_ROOT
from pipeline.core.stage import stage_modules

SCRIPTS = PROJECT_ROOT / "scripts"


def _files(folder: Path, *suffixes: str) -> set[str]:
    return {p.relative_to(folder).as_posix() for p in folder.rglob("*")
            if p.is_file() and p.suffix in suffixes and "__pycache__" not in p.parts}


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    """The project's wheel, built once from a copy of what it is made of."""
    src = tmp_path_factory.mktemp("src")
    for name in ("pyproject.toml", "setup.py", "README.md"):
        shutil.copy2(PROJECT_ROOT / name, src / name)
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc")
    for name in ("pipeline", "conf", "scripts/round_check"):
        shutil.copytree(PROJECT_ROOT / name, src / name, ignore=ignore)
    out = tmp_path_factory.mktemp("dist")
    # the installed setuptools when it is one pyproject.toml accepts (torch pulls a new one in), else pip's own
    isolated = int(importlib.metadata.version("setuptools").split(".")[0]) < 77
    p = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(out), str(src),
                        *([] if isolated else ["--no-build-isolation"])], capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr[-3000:]
    (path,) = out.glob("boom_ik-*.whl")
    return path


@pytest.mark.slow
def test_the_wheel_carries_the_configs_the_checker_and_both_commands(wheel):
    names = set(zipfile.ZipFile(wheel).namelist())
    packaged = {n.removeprefix("pipeline/_conf/") for n in names if n.startswith("pipeline/_conf/")}
    conf = _files(PROJECT_ROOT / "conf", ".yaml", ".csv")
    assert "config.yaml" in conf and "tunnel/profiles/d_5x5.csv" in conf
    assert packaged == conf  # every config file, nothing else
    checker = {n.removeprefix("round_check/") for n in names if n.startswith("round_check/")}
    assert checker == _files(SCRIPTS / "round_check", ".py") and "__main__.py" in checker
    code = {n for n in names if n.startswith("pipeline/") and n.endswith(".py")}
    assert code == {f"pipeline/{f}" for f in _files(PROJECT_ROOT / "pipeline", ".py")}
    (entry,) = [n for n in names if n.endswith(".dist-info/entry_points.txt")]
    text = zipfile.ZipFile(wheel).read(entry).decode()
    assert "boom-ik = pipeline.__main__:main" in text and "boom-ik-check-round = round_check.cli:main" in text


@pytest.mark.slow
def test_the_packaged_configs_compose_as_the_checkouts(wheel, tmp_path):
    """The wheel's copy of conf/, composed where it lands, gives the checkout's composition."""
    from hydra import compose, initialize_config_dir

    zipfile.ZipFile(wheel).extractall(tmp_path)
    with initialize_config_dir(config_dir=str(tmp_path / "pipeline" / "_conf"), version_base="1.3"):
        packaged = compose(config_name="config", overrides=["rig=twin", "experiment=tiny"])
    assert OmegaConf.to_container(packaged) == OmegaConf.to_container(config.compose(["rig=twin", "experiment=tiny"]))


# ------------------------------------------------------------------------- checkout or not, cheap
def test_the_config_dir_is_the_checkouts_only_in_a_checkout(tmp_path):
    assert config.config_dir() == PROJECT_ROOT / "conf" == config.CONF_DIR and config.IN_CHECKOUT
    assert config.config_dir(tmp_path) == config.PACKAGED_CONF  # site-packages: no conf/ there
    (tmp_path / "conf").mkdir()
    assert config.config_dir(tmp_path) == config.PACKAGED_CONF  # a conf/ folder alone is not a checkout
    (tmp_path / "pyproject.toml").write_text("")
    assert config.config_dir(tmp_path) == tmp_path / "conf"
    (tmp_path / "pyproject.toml").unlink()
    (tmp_path / "dvc.yaml").write_text("")
    assert config.config_dir(tmp_path) == tmp_path / "conf"
    assert config.PACKAGED_CONF == PROJECT_ROOT / "pipeline" / "_conf"


def test_outside_a_checkout_paths_and_the_store_are_the_working_directorys(tmp_path, monkeypatch):
    assert config.project_path("data") == PROJECT_ROOT / "data" and config.main_root() == PROJECT_ROOT
    packaged = tmp_path / "site" / "_conf"
    (packaged / "tunnel" / "profiles").mkdir(parents=True)
    (packaged / "tunnel" / "profiles" / "d.csv").write_text("y,z,kind\n")
    monkeypatch.setattr(config, "IN_CHECKOUT", False)
    monkeypatch.setattr(config, "CONF_DIR", packaged)
    monkeypatch.chdir(tmp_path)
    assert config.base_dir() == config.main_root() == tmp_path
    assert config.project_path("data") == tmp_path / "data"
    assert config.project_path("/abs/x.csv") == Path("/abs/x.csv")
    assert config.project_path("conf/tunnel/profiles/d.csv") == packaged / "tunnel" / "profiles" / "d.csv"
    assert config.project_path("conf/tunnel/profiles/no.csv") == tmp_path / "conf/tunnel/profiles/no.csv"
    (tmp_path / "conf" / "tunnel" / "profiles").mkdir(parents=True)
    (tmp_path / "conf" / "tunnel" / "profiles" / "d.csv").write_text("y,z,kind\n")  # the user's own wins
    assert config.project_path("conf/tunnel/profiles/d.csv") == tmp_path / "conf/tunnel/profiles/d.csv"

    from pipeline.tracking.runs import TrackingSettings, resolve_uri

    monkeypatch.delenv("MLFLOW_TRACKING_URI", raising=False)
    assert resolve_uri(None) == f"sqlite:///{tmp_path / 'mlflow.db'}"
    settings = TrackingSettings.from_config({"enabled": False, "experiment": "x"})
    assert settings.artifact_root == tmp_path / "mlartifacts"


def test_the_checker_finds_its_configs_as_the_stages_do(tmp_path, monkeypatch):
    sys.path.insert(0, str(SCRIPTS))
    try:
        paths = importlib.import_module("round_check.paths")  # the checker's own module, through the script's path
    finally:
        sys.path.remove(str(SCRIPTS))
    assert paths.IN_CHECKOUT and paths.CONF_DIR == config.CONF_DIR and paths.base_dir() == PROJECT_ROOT
    assert paths.PACKAGED_CONF == SCRIPTS / "pipeline" / "_conf"  # in the wheel: site-packages/pipeline/_conf
    assert not paths.in_checkout(tmp_path)
    packaged = tmp_path / "_conf"
    (packaged / "boom").mkdir(parents=True)
    (packaged / "boom" / "b.yaml").write_text("{}")
    monkeypatch.setattr(paths, "IN_CHECKOUT", False)
    monkeypatch.setattr(paths, "CONF_DIR", packaged)
    monkeypatch.chdir(tmp_path)
    assert paths.project_path("plan.csv") == tmp_path / "plan.csv"
    assert paths.project_path("conf/boom/b.yaml") == packaged / "boom" / "b.yaml"


# ------------------------------------------------------------------------- the commands
def test_boom_ik_lists_every_stage_and_names_the_closest_to_a_typo(capsys):
    from pipeline.__main__ import main

    stages = [p.stem for p in sorted((PROJECT_ROOT / "pipeline").glob("*.py")) if "run_stage(" in p.read_text()]
    assert list(stage_modules()) == stages and len(stages) >= 19  # tests/test_exit_codes.py's list
    assert main(["--help"]) == 0
    out = capsys.readouterr().out
    for name, line in stage_modules().items():
        assert line and f"  {name} " in out and line in out, name
    assert main([]) == 2 and "solve" in capsys.readouterr().err
    assert main(["sovle", "plan=x.csv"]) == 2
    assert "unknown stage 'sovle'; did you mean 'solve'?" in capsys.readouterr().err


@pytest.mark.slow
def test_boom_ik_runs_a_stage_as_python_m_does(tmp_path):
    """``python -m pipeline demo_face ...`` (the ``boom-ik`` entry) from a folder outside the checkout: the
    stage composes, takes its overrides and writes where they say; a bad setting keeps the stage's code."""
    env = {**os.environ, "PYTHONPATH": str(PROJECT_ROOT)}
    cmd = [sys.executable, "-m", "pipeline", "demo_face", f"paths.data={tmp_path}/data",
           f"hydra.run.dir={tmp_path}/hydra"]
    p = subprocess.run(cmd, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr[-3000:]
    assert (tmp_path / "data" / "plans" / "demo_face.csv").is_file()
    p = subprocess.run([*cmd, "boom=jumbo9"], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    assert p.returncode == 2 and "boom/jumbo9" in p.stderr, p.stderr[-2000:]


def test_the_checker_runs_as_a_module(tmp_path):
    env = {**os.environ, "PYTHONPATH": str(SCRIPTS)}
    p = subprocess.run([sys.executable, "-m", "round_check", "--help"], cwd=tmp_path, env=env, capture_output=True,
                       text=True, timeout=120)
    assert p.returncode == 0 and "--realised" in p.stdout, p.stderr[-2000:]
