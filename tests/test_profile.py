"""Tunnels of any profile: the file's checks, the distances against brute force and the horseshoe, the safety
model and its compiled kernels on a profile, and the rest of the stack reading `tunnel=profile`."""

import math
from pathlib import Path

import numpy as np
import pytest
import torch

from pipeline.assembly.build import build_safety, build_tunnel
from pipeline.core.config import CONF_DIR
from pipeline.core.errors import ConfigError, InputError
from pipeline.geometry.compiled_kinematics import ChainArrays, SafetyArrays, chain_values, clearance_values
from pipeline.geometry.profile import Profile, read_profile_csv
from pipeline.geometry.tunnel import SURFACES, Horseshoe

D = torch.float64
PROFILES = CONF_DIR / "tunnel" / "profiles"
EXAMPLES = sorted(p.name for p in PROFILES.glob("*.csv"))
SAFETY = {"self": 0.1, "wall": 0.5, "ground": 0.1, "arch": 0.1}
# the reference horseshoe's arch as 64 chords of radius 2.5 m: each chord lies at most r (1 - cos(pi / 128))
# inside the arc (its sagitta), plus the file's rounding of each vertex to the micrometre
SAGITTA = 2.5 * (1 - math.cos(math.pi / 128)) + 1e-6


def profile_node(name: str) -> dict:
    return {"kind": "profile", "file": str(PROFILES / name)}


def write(tmp_path: Path, rows: list[tuple], header="y,z,surface") -> Path:
    path = tmp_path / "profile.csv"
    path.write_text("\n".join([header, *(",".join(str(v) for v in r) for r in rows)]) + "\n")
    return path


SQUARE = [(2, 0, "ground"), (2, 4, "arch"), (-2, 4, "wall"), (-2, 0, "wall")]


# --- the file ---------------------------------------------------------------------------------------------

def test_every_example_profile_reads_and_is_a_simple_polygon_with_every_kind():
    assert {"horseshoe_5x5.7.csv", "d_5x5.csv", "box_5.5x4.5.csv", "three_centred_6x5.5.csv"} <= set(EXAMPLES)
    for name in EXAMPLES:
        yz, kinds = read_profile_csv(PROFILES / name)
        assert 3 <= len(yz) <= 200 and set(kinds.tolist()) == {0, 1, 2}


@pytest.mark.parametrize(("rows", "header", "message"), [
    (SQUARE, "y,z", r"without column\(s\) \['surface'\]"),
    (SQUARE[:2], "y,z,surface", r"2 vertices; a tunnel profile needs 3"),
    ([(2, 0, "ground"), (2, "x", "arch"), *SQUARE[2:]], "y,z,surface", r"row 3: y = '2', z = 'x': expected two finite"),
    ([(2, 0, "ground"), (2, "inf", "arch"), *SQUARE[2:]], "y,z,surface", r"row 3: .* expected two finite"),
    ([(2, 0, "ground"), (2, 4, "roof"), *SQUARE[2:]], "y,z,surface", r"row 3: surface 'roof': expected one of"),
    ([(2, 0, "ground"), (2, 0, "wall"), (2, 4, "arch"), (-2, 4, "wall"), (-2, 0, "wall")], "y,z,surface",
     r"rows 2 and 3: a segment of 0 m \(a repeated vertex\)"),
    ([(2, 0, "ground"), (2, 4, "wall"), (-2, 4, "wall"), (-2, 0, "wall")], "y,z,surface",
     r"no segment of kind \['arch'\]"),
    ([(2, 0, "ground"), (-2, 4, "arch"), (2, 4, "wall"), (-2, 0, "wall")], "y,z,surface",
     r"the segment from row 2 and the one from row 4 meet"),
])
def test_a_bad_profile_is_refused_naming_the_file_and_the_row(tmp_path, rows, header, message):
    path = write(tmp_path, rows, header)
    with pytest.raises(InputError, match=message) as e:
        read_profile_csv(path)
    assert str(path) in str(e.value)


def test_profile_settings_are_checked_before_the_file(tmp_path):
    with pytest.raises(ConfigError, match=r"tunnel.file = None: tunnel=profile needs the profile CSV"):
        build_tunnel({"kind": "profile", "file": None})
    with pytest.raises(ConfigError, match=r"tunnel.kind = 'oval': expected one of \['horseshoe', 'profile'\]"):
        build_tunnel({"kind": "oval"})
    with pytest.raises(ConfigError, match=r"unknown field\(s\) \['width'\] for kind profile"):
        build_tunnel({**profile_node("d_5x5.csv"), "width": 5.0})
    with pytest.raises(InputError, match=r"35 vertices; .* tunnel.max_vertices = 10"):
        build_tunnel({**profile_node("d_5x5.csv"), "max_vertices": 10})
    with pytest.raises(InputError, match=r"no such tunnel profile"):
        build_tunnel({"kind": "profile", "file": str(tmp_path / "none.csv")})
    assert build_tunnel({"width": 5.0, "wall_height": 3.2}) == Horseshoe()  # no kind: the horseshoe, as before


def test_the_direction_round_the_profile_does_not_matter():
    yz, kinds = read_profile_csv(PROFILES / "box_5.5x4.5.csv")
    forward = Profile(yz, kinds)
    # reversed: vertex i+1 .. i, each segment keeping its kind (segment k from v_k to v_k+1 becomes v_k+1 -> v_k)
    backward = Profile(yz[::-1].copy(), np.roll(kinds[::-1], -1).copy())
    g = torch.Generator().manual_seed(0)
    y, z = torch.rand(4000, generator=g, dtype=D) * 7 - 3.5, torch.rand(4000, generator=g, dtype=D) * 6 - 0.8
    a, b = forward.surface_distances(y, z), backward.surface_distances(y, z)
    for k in SURFACES:
        torch.testing.assert_close(a[k], b[k], rtol=0, atol=1e-12)


# --- distances against independent values ---------------------------------------------------------------------

def _segments_of(profile: Profile, kind: int) -> np.ndarray:
    return profile.segments[profile.kinds == kind]


def _point_to_segments(p: np.ndarray, segs: np.ndarray) -> np.ndarray:
    """Exact distance from points (n, 2) to the nearest of segments (m, 4), numpy."""
    a, b = segs[None, :, :2], segs[None, :, 2:]
    ab = b - a
    t = np.clip(((p[:, None] - a) * ab).sum(-1) / (ab * ab).sum(-1), 0, 1)
    return np.linalg.norm(p[:, None] - (a + t[..., None] * ab), axis=-1).min(-1)


def _inside(p: np.ndarray, profile: Profile) -> np.ndarray:
    """Winding number (a second rule beside the model's even-odd count)."""
    v = profile.yz[None] - p[:, None]
    w = np.roll(v, -1, axis=1)
    ang = np.arctan2(v[..., 0] * w[..., 1] - v[..., 1] * w[..., 0], (v * w).sum(-1))
    return np.abs(ang.sum(-1)) > np.pi


@pytest.mark.parametrize("name", ["d_5x5.csv", "box_5.5x4.5.csv", "three_centred_6x5.5.csv"])
def test_capsule_distance_is_the_dense_minimum_along_the_axis(name):
    """Axes inside the profile: the least distance of 2 001 points along each to each kind (exact point-segment
    distances, numpy) equals the model's segment-pair answer, to the sampling's step."""
    profile = Profile.from_file(PROFILES / name)
    g = np.random.default_rng(4)
    a = np.stack([g.uniform(*profile.y_range, 200), g.uniform(*profile.z_range, 200)], -1)
    b = a + g.normal(0, 1.5, (200, 2))
    s = np.linspace(0, 1, 2001)
    pts = a[:, None] + s[None, :, None] * (b - a)[:, None]  # (axes, samples, 2)
    inside = _inside(pts.reshape(-1, 2), profile).reshape(pts.shape[:2]).all(1)  # the whole axis, not its ends
    a, b, pts = a[inside], b[inside], pts[inside]
    assert len(a) > 60
    start = torch.tensor(np.concatenate([np.zeros((len(a), 1)), a], 1))
    axis = torch.tensor(np.concatenate([np.ones((len(a), 1)), b - a], 1))
    values, frac = profile.capsule_distances(start, axis)
    step = np.linalg.norm(b - a, axis=1) / 2000
    for k in range(3):
        dense = _point_to_segments(pts.reshape(-1, 2), _segments_of(profile, k)).reshape(pts.shape[:2]).min(1)
        assert np.all(np.abs(values[:, k].numpy() - dense) <= step + 1e-12), (name, k)
        at = a + frac[:, k].numpy()[:, None] * (b - a)  # the reported place reaches the reported value
        np.testing.assert_allclose(_point_to_segments(at, _segments_of(profile, k)), values[:, k].numpy(), atol=1e-9)


def test_an_axis_leaving_the_profile_is_negative_for_the_kind_it_left_through():
    profile = Profile.from_file(PROFILES / "box_5.5x4.5.csv")  # flat roof at z = 4.5
    start = torch.tensor([[0.0, 0.0, 4.0], [0.0, 1.0, 2.0], [0.0, 0.0, 4.0]], dtype=D)
    axis = torch.tensor([[1.0, 0.0, 0.8], [1.0, 3.0, 0.0], [1.0, 0.0, 0.3]], dtype=D)  # roof, wall, inside
    values, frac = profile.capsule_distances(start, axis)
    assert values[0, 2] == pytest.approx(-0.3, abs=1e-12) and frac[0, 2] == 1.0  # 0.3 m above the roof
    assert values[1, 0] == pytest.approx(-1.25, abs=1e-12)  # its end 1.25 m beyond the wall at y = 2.75
    assert bool((values[2] > 0).all()) and values[2, 2] == pytest.approx(0.2, abs=1e-12)


def test_the_horseshoe_as_a_polyline_gives_the_horseshoes_clearances_within_the_chord_error(jumbo8):
    """The reference horseshoe and its 64-chord polyline: on 6 000 configurations of the whole joint box, every
    clearance of a configuration that passes in either agrees within the sagitta (0.75 mm), and the two checks
    disagree only where a clearance is within the sagitta of zero."""
    horse = build_safety(jumbo8, {"width": 5.0, "wall_height": 3.2}, SAFETY)
    poly = build_safety(jumbo8, profile_node("horseshoe_5x5.7.csv"), SAFETY)
    g = torch.Generator().manual_seed(7)
    lo, hi = jumbo8.limits(D)
    q = lo + torch.rand(6000, jumbo8.n_joints, generator=g, dtype=D) * (hi - lo)
    ch, cp = horse.clearances(q), poly.clearances(q)
    tunnel_h = torch.stack([ch[k] for k in SURFACES], -1)
    tunnel_p = torch.stack([cp[k] for k in SURFACES], -1)
    both = (tunnel_h.min(-1).values >= 0) | (tunnel_p.min(-1).values >= 0)
    assert int(both.sum()) > 500
    gap = (tunnel_h - tunnel_p)[both].abs().max()
    assert float(gap) <= SAGITTA + 1e-12
    disagree = (tunnel_h.min(-1).values >= 0) != (tunnel_p.min(-1).values >= 0)
    assert bool((tunnel_h.min(-1).values[disagree].abs() <= SAGITTA + 1e-12).all())
    torch.testing.assert_close(ch["self"], cp["self"], rtol=0, atol=0)  # self does not depend on the drift


def test_profile_clearance_gradients_are_their_finite_differences(jumbo8):
    safety = build_safety(jumbo8, profile_node("d_5x5.csv"), SAFETY)
    g = torch.Generator().manual_seed(2)
    lo, hi = jumbo8.limits(D)
    q = lo + torch.rand(300, jumbo8.n_joints, generator=g, dtype=D) * (hi - lo)
    values, grads = safety.clearances_with_jacobians(jumbo8.frames(q))
    h = 1e-6
    checked = 0
    for j in range(jumbo8.n_joints):
        dq = torch.zeros_like(q)
        dq[:, j] = h
        plus, minus = safety.clearances(q + dq), safety.clearances(q - dq)
        for k in SURFACES:
            fd = (plus[k] - minus[k]) / (2 * h)
            # a minimum switching between segments or bodies inside the step has no derivative: leave those out
            smooth = ((plus[k] + minus[k] - 2 * values[k]).abs() < 1e-9) & (values[k] > -0.3)
            assert torch.allclose(grads[k][smooth, j], fd[smooth], atol=1e-5), (j, k)
            checked += int(smooth.sum())
    assert checked > 3000


def test_penalties_on_a_profile_train_a_configuration_back_inside(jumbo8):
    """The hinge of the profile clearances has a gradient that clears what it penalises (autograd through the
    segment distances), as the training penalties need."""
    safety = build_safety(jumbo8, profile_node("box_5.5x4.5.csv"), SAFETY)
    q = torch.tensor([[0.0, math.radians(55), 4.4, 0.0, 0.0, 0.0, 0.0, 2.5]], dtype=D, requires_grad=True)
    start = sum(float(v.detach()) for v in safety.penalties(safety.clearances(q)).values())
    assert start > 0  # the boom lifted into the flat roof
    opt = torch.optim.SGD([q], lr=0.05)
    for _ in range(200):
        opt.zero_grad()
        loss = sum(v.sum() for v in safety.penalties(safety.clearances(q)).values())
        loss.backward()
        opt.step()
    assert float(loss) < 0.05 * start


# --- the compiled kernels -------------------------------------------------------------------------------------

@pytest.mark.parametrize("name", ["d_5x5.csv", "three_centred_6x5.5.csv", "box_5.5x4.5.csv"])
def test_compiled_profile_clearances_and_gradients_are_the_torch_ones(jumbo8, name):
    safety = build_safety(jumbo8, profile_node(name), SAFETY)
    g = torch.Generator().manual_seed(5)
    lo, hi = jumbo8.limits(D)
    q = lo + torch.rand(2000, jumbo8.n_joints, generator=g, dtype=D) * (hi - lo)
    chain = ChainArrays.from_boom(jumbo8)
    frames, _, _ = chain_values(chain, q.numpy())
    C, G = clearance_values(chain, SafetyArrays.from_model(safety), frames)
    values, grads = safety.clearances_with_jacobians(torch.tensor(frames))
    for i, k in enumerate(("self", *SURFACES)):
        np.testing.assert_allclose(C[:, i], values[k].numpy(), rtol=0, atol=1e-12)
        np.testing.assert_allclose(G[:, i], grads[k].numpy(), rtol=0, atol=1e-10)


# --- the rest of the stack reads the profile --------------------------------------------------------------

def _inside_less(points: np.ndarray, profile: Profile, inset: float) -> np.ndarray:
    """(y, z) points inside the polygon (winding number) and at least ``inset`` from every segment: numpy."""
    all_segments = profile.segments
    return _inside(points, profile) & (_point_to_segments(points, all_segments) >= inset - 1e-9)


@pytest.mark.parametrize("name", ["d_5x5.csv", "box_5.5x4.5.csv", "three_centred_6x5.5.csv"])
def test_the_face_designer_designs_a_drillable_face_for_a_profile(jumbo8, name):
    """Every hole type, every collar inside the profile less the 0.2 m inset (a second inside rule), lifters on
    the floor as it runs (the box's floor falls 2 % to the right), contour holes looking out of the drift."""
    from pipeline.plans.demo_face import demo_face

    safety = build_safety(jumbo8, profile_node(name), SAFETY)
    holes = demo_face(safety=safety).holes
    assert set(holes["hole_type"]) == {"cut", "relief", "stoping", "lifter", "contour"} and len(holes) >= 50
    collars = holes[["collar_y", "collar_z"]].to_numpy()
    assert _inside_less(collars, safety.tunnel, 0.2).all()
    floor = _segments_of(safety.tunnel, SURFACES.index("ground"))
    lifters = holes[holes["hole_type"] == "lifter"][["collar_y", "collar_z"]].to_numpy()
    assert np.allclose(_point_to_segments(lifters, floor), _point_to_segments(lifters[:1], floor)[0], atol=1e-6)
    contour = holes[holes["hole_type"] == "contour"]
    toes = contour[["toe_y", "toe_z"]].to_numpy()
    assert (~_inside_less(toes, safety.tunnel, 0.0)).mean() > 0.9  # look-out: their toes end beyond the profile


@pytest.mark.slow
def test_a_study_in_a_profile_drift_draws_its_holes_there_and_trains(tmp_path, make_cfg):
    """generate and train (tiny) with tunnel=profile: the training holes and test groups lie in the box
    profile less the inset (a second inside rule), their feed beams clear of it; the network trains against
    that drift's penalties (its MLflow run logs the profile's collision counts)."""
    from mlflow.tracking import MlflowClient

    from pipeline import generate, train
    from pipeline.data.hole_sets import read_hole_poses

    over = ["tunnel=profile", f"tunnel.file={PROFILES / 'box_5.5x4.5.csv'}", "train.steps=60", "train.seeds=1"]
    generate.run(make_cfg(tmp_path, *over))
    profile = Profile.from_file(PROFILES / "box_5.5x4.5.csv")
    holes = tmp_path / "data" / "holes"
    for name in ("train.parquet", "test_group_1.parquet"):
        _, pose = read_hole_poses(holes, name)
        assert _inside_less(pose[:, 1:3].numpy(), profile, 0.2).all(), name
        assert (pose[:, 1:3].numpy()[:, 1] > 3.9).any()  # under the box's roof corners too, not only a horseshoe
    train.run(make_cfg(tmp_path, *over, "method=cuikm"))
    client = MlflowClient(f"sqlite:///{tmp_path}/mlflow.db")
    (run,) = client.search_runs([client.get_experiment_by_name("boom-ik-tiny").experiment_id],
                                "tags.stage = 'train'")
    assert run.info.status == "FINISHED" and run.data.params["tunnel.kind"] == "profile"
    assert run.data.params["tunnel_profile_md5"] == profile.md5  # a changed file is another training
