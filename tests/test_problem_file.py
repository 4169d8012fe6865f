"""The round's problem on disk (``<stem>_problem.npz``): written and read back exactly, and every file that
is not the problem of this rig, plan and boom refused with the file and the reason, never loaded as code."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.core.errors import InputError
from pipeline.round.problem_file import RoundProblem, load_problem, save_problem

BOOMS, HOLES, JOINTS = ("L", "R"), ("h1", "h2", "h3"), ("q1", "q2", "q3", "q4")


def problem(seed=0) -> RoundProblem:
    rng = np.random.default_rng(seed)
    reach = np.array([[True, False, True], [True, True, False]])
    joints = rng.normal(size=(2, 3, 4))
    joints[0, 1] = np.nan  # no solution where the boom cannot drill the hole
    return RoundProblem(BOOMS, HOLES, JOINTS, reach, joints, ("", "", "no boom can drill it ok: L x, R y"))


def written(tmp_path, p=None):
    path = tmp_path / "p_problem.npz"
    save_problem(p or problem(), path)
    return path


def test_a_problem_reads_back_exactly(tmp_path):
    p = problem()
    back = load_problem(written(tmp_path, p), BOOMS, HOLES, JOINTS)
    np.testing.assert_array_equal(back.reach, p.reach)
    np.testing.assert_array_equal(back.joints, p.joints)  # bit for bit, NaN where unsolved
    assert (back.booms, back.hole_ids, back.joint_names, back.reasons) == (BOOMS, HOLES, JOINTS, p.reasons)


@pytest.mark.parametrize("args, message", [
    ((("L", "M"), HOLES, JOINTS), "'booms'"),
    ((BOOMS, ("h1", "h3", "h2"), JOINTS), "'hole_ids'"),
    ((BOOMS, HOLES, ("q1", "q2", "q3")), "'joint_names'"),
])
def test_a_problem_of_another_rig_plan_or_boom_is_refused(tmp_path, args, message):
    with pytest.raises(InputError, match=f"p_problem.npz: {message}.*re-run schedule"):
        load_problem(written(tmp_path), *args)


def _rewrite(path, **arrays):
    with np.load(path, allow_pickle=False) as z:
        a = {k: z[k] for k in z.files}
    a.update(arrays)
    with open(path, "wb") as f:
        np.savez(f, **{k: v for k, v in a.items() if v is not None})


@pytest.mark.parametrize("change, message", [
    ({"reach": np.ones((2, 3), np.int8)}, "'reach' is int8"),
    ({"joints": np.zeros((2, 3, 4), np.float32)}, "'joints' is float32"),
    ({"joints": np.zeros((2, 2, 4))}, r"'joints' is float64 \(2, 2, 4\)"),
    ({"reasons": np.array(["", ""])}, "'reasons' has 2 entries for 3 holes"),
    ({"version": np.int64(7)}, "version"),
    ({"joints": None}, "no 'joints' array"),
    ({"joints": np.full((2, 3, 4), np.nan)}, "boom L drills hole h1 ok but has no finite joints"),
])
def test_a_malformed_problem_is_named(tmp_path, change, message):
    path = written(tmp_path)
    _rewrite(path, **change)
    with pytest.raises(InputError, match=message):
        load_problem(path, BOOMS, HOLES, JOINTS)


def test_an_object_array_is_refused_without_running_it(tmp_path):
    """A pickled array (what could run code on load) is refused by ``allow_pickle=False``, named."""
    path = written(tmp_path)
    _rewrite(path, reasons=np.array(["", "", {"a": 1}], dtype=object))
    with pytest.raises(InputError, match="cannot read it as a round problem"):
        load_problem(path, BOOMS, HOLES, JOINTS)


def test_a_file_that_is_no_archive_is_named(tmp_path):
    path = tmp_path / "p_problem.npz"
    path.write_text("hole_id,collar_x\n")
    with pytest.raises(InputError, match="p_problem.npz: cannot read it as a round problem"):
        load_problem(path, BOOMS, HOLES, JOINTS)
