"""The round's set of files (pipeline/round/output.py): checked before any work, published whole.

Each case is one defect a user met: ``schedule plan=a_round.csv out=a_round.csv`` replaced the plan,
``out=x.json`` made a folder ``x.json``, a folder ``c_round.json`` in the way failed only after the CSV
and trajectory were already moved in, figures switched off left the old PNGs beside the new set.
"""

import json
import os

import pytest

from pipeline.core.errors import InputError
from pipeline.core.io import file_md5, publish
from pipeline.round.output import SUFFIXES, round_paths, write_round_set


@pytest.fixture
def plan(tmp_path):
    p = tmp_path / "a.csv"
    p.write_text("hole_id,collar_x,collar_y,collar_z,toe_x,toe_y,toe_z\n")
    return p


def test_default_and_named_sets(plan, tmp_path):
    assert round_paths(plan, None)["round"] == tmp_path / "a_round.csv"
    assert round_paths(plan, tmp_path / "r" / "b_round.csv")["trajectory"] == tmp_path / "r" / "b_trajectory.csv"
    assert round_paths(plan, tmp_path / "b.csv")["json"] == tmp_path / "b_round.json"
    assert round_paths(plan, tmp_path / "rounds")["replay"] == tmp_path / "rounds" / "a_round_replay.html"
    (tmp_path / "there").mkdir()
    assert round_paths(plan, tmp_path / "there").folder == tmp_path / "there"


@pytest.mark.parametrize("name,out", [("a_round.csv", "a_round.csv"), ("P_trajectory.csv", "P.csv"),
                                      ("P_round.json", "P_round.csv")])
def test_an_input_is_never_a_file_of_the_set(tmp_path, name, out):
    plan = tmp_path / name
    plan.write_text("hole_id\n")
    before = plan.read_bytes()
    with pytest.raises(InputError, match="out = .*is the input .* itself"):
        round_paths(plan, tmp_path / out)
    assert plan.read_bytes() == before


def test_a_hard_link_to_the_plan_is_the_plan(plan, tmp_path):
    os.link(plan, tmp_path / "b_round.csv")
    with pytest.raises(InputError, match="is the input"):
        round_paths(plan, tmp_path / "b_round.csv")
    with pytest.raises(InputError, match="is the input"):
        round_paths(tmp_path / "c.csv", tmp_path / "b_round.csv", inputs=[plan])


def test_other_suffixes_and_folders_in_the_way_are_refused(plan, tmp_path):
    with pytest.raises(InputError, match="out = .*x.json: expected a folder or the round table's name"):
        round_paths(plan, tmp_path / "x.json")
    assert not (tmp_path / "x.json").exists()
    (tmp_path / "c_round.json").mkdir()
    with pytest.raises(InputError, match="c_round.json is an existing folder"):
        round_paths(plan, tmp_path / "c.csv")
    (tmp_path / "f").write_text("")
    with pytest.raises(InputError, match="is a file, not a folder"):
        round_paths(plan, tmp_path / "f" / "d.csv")


def _writers(kinds):
    return {k: (lambda p, k=k: p.write_text(f"new {k}\n")) for k in kinds}


def test_the_set_is_published_whole_with_its_manifest_and_no_stale_sibling(plan, tmp_path):
    paths = round_paths(plan, None)
    every = [k for k in SUFFIXES if k != "json"]
    write_round_set(paths, {"makespan_s": 1.0}, _writers(every))
    assert all(paths[k].exists() for k in SUFFIXES)
    second = write_round_set(paths, {"makespan_s": 2.0}, _writers(["round", "trajectory"]))  # figures off
    assert not paths["face"].exists() and not paths["gantt"].exists() and not paths["replay"].exists()
    on_disk = json.loads(paths["json"].read_text())
    assert on_disk == second and on_disk["makespan_s"] == 2.0
    assert on_disk["files"] == {paths[k].name: file_md5(paths[k]) for k in ("round", "trajectory")}
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".a_round.") and p.is_dir()]  # stage gone


def test_a_failing_writer_leaves_the_previous_set(plan, tmp_path):
    paths = round_paths(plan, None)
    write_round_set(paths, {"makespan_s": 1.0}, _writers(["round", "trajectory"]))
    before = {k: paths[k].read_bytes() for k in ("round", "trajectory", "json")}

    def broken(_p):
        raise OSError("disk full")

    with pytest.raises(OSError, match="disk full"):
        write_round_set(paths, {"makespan_s": 2.0}, {**_writers(["round"]), "trajectory": broken})
    assert {k: paths[k].read_bytes() for k in before} == before


def test_publish_moves_nothing_when_one_destination_is_a_folder(tmp_path):
    a, b = tmp_path / "a.new", tmp_path / "b.new"
    a.write_text("a"), b.write_text("b")
    (tmp_path / "b").mkdir()
    with pytest.raises(InputError, match="b is in the way"):
        publish({a: tmp_path / "a", b: tmp_path / "b"}, tmp_path / ".lock")
    assert not (tmp_path / "a").exists() and a.exists()


def test_publish_replaces_a_folder_whole_with_its_files(tmp_path):
    """A set of files and a folder (a training's chosen network and its seeds folder): the old folder goes whole,
    none of its files is left beside the new ones, and a file where the folder should be stops it all first."""
    new, dst = tmp_path / "seeds.new", tmp_path / "seeds"
    new.mkdir(), dst.mkdir()
    (new / "s1.pt").write_text("new 1")
    (dst / "s1.pt").write_text("old 1"), (dst / "s9.pt").write_text("old 9")
    top = tmp_path / "net.new"
    top.write_text("net")
    publish({top: tmp_path / "net.pt"}, tmp_path / ".lock", folders={new: dst})
    assert sorted(p.name for p in dst.iterdir()) == ["s1.pt"] and (dst / "s1.pt").read_text() == "new 1"
    assert (tmp_path / "net.pt").read_text() == "net" and not new.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == [".lock", "net.pt", "seeds"]  # the old folder: gone
    other, top = tmp_path / "other.new", tmp_path / "net2.new"
    other.mkdir(), top.write_text("net 2")
    (tmp_path / "blocked").write_text("a file")
    with pytest.raises(InputError, match="blocked is in the way"):
        publish({top: tmp_path / "net.pt"}, tmp_path / ".lock", folders={other: tmp_path / "blocked"})
    assert (tmp_path / "net.pt").read_text() == "net" and other.is_dir() and top.exists()
