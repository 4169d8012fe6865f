"""The IK libraries a robotics engineer would pick instead of this project, behind the same
:class:`Solver` interface: Peter Corke's Robotics Toolbox (its C++ ``ik_LM``) and Pinocchio (the
closed-loop IK of its documentation, CLIK). Both are an optional extra::

    pip install -e ".[peers]"

Both chains are built from the same :class:`Boom` (``conf/boom/*.yaml`` parsed once): every D-H row
becomes the elementary transforms of its convention (:func:`elementary_chain`), so nothing is copied
by hand, and tests/test_peers.py checks their forward kinematics against the project's.

Both get the same targets as the project's solvers, a hole ``[p, p']``, with the roll about the drill
axis left free, each the way its library allows:

* Robotics Toolbox: ``mask`` weights the error in the **base** frame, so ``[1, 1, 1, 1, 1, 0]`` frees
  a rotation about the base z, not about the drill axis (used directly it misses holes by metres).
  Each hole therefore rotates the chain's base by ``R_b`` with ``R_b u = e_z`` (``u`` the drill
  direction): in that frame the drill axis is z and the mask frees exactly the roll. The tolerance
  is set far below the default (which stops about 1 mm short of the hole), and ``ik_LM`` is the C++
  solver (``ikine_LM`` is the pure-Python one).
* Pinocchio: the error ``log6`` is in the tool's own frame, whose z is the drill axis, so its last
  row is dropped (5 task rows); damped Gauss-Newton steps (CLIK with unit gain), joints kept in
  their ranges, random restarts when a start does not converge.

Neither knows the tunnel or the boom's own bodies: the benchmark checks their joints with the
project's safety model, as it does every method's.
"""

from __future__ import annotations

import importlib
import math

import numpy as np
import torch

from pipeline.geometry.kinematics import Boom
from pipeline.solvers.base import HoleTargets, Solver, Targets

PEERS_MISSING = "peers extra not installed: pip install -e '.[peers]'"
PEER_MODULES = {"rtb_ik_lm": "roboticstoolbox", "pinocchio_clik": "pinocchio"}


class PeersUnavailable(ImportError):
    """A peer library is not installed (the ``peers`` extra)."""


def missing_peers() -> list[str]:
    """The peer libraries that cannot be imported here (empty: the extra is installed)."""
    missing = []
    for module in PEER_MODULES.values():
        try:
            importlib.import_module(module)
        except ImportError:
            missing.append(module)
    return missing


def _import(module: str):
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        raise PeersUnavailable(f"{PEERS_MISSING} ({module}: {exc})") from None


# ---------------------------------------------------------------------------------------------- the chain
def elementary_chain(boom: Boom) -> list[tuple[str, str, float | None, int | None]]:
    """The boom's chain as elementary transforms ``(kind, axis, value, joint)``: ``kind`` ``"R"``
    (rotation) or ``"t"`` (translation) about/along ``axis`` ``"x" | "y" | "z"``; a constant has its
    ``value`` (rad / m), a joint its index into ``q`` (its offset is the constant before it).

    Modified D-H: ``Rx(alpha) tx(a) Rz(theta) tz(d)``; standard: ``Rz(theta) tz(d) tx(a) Rx(alpha)``;
    then the tool offset. A locked joint is a constant; zero constants are left out."""
    by_row: dict[tuple[int, str], int] = {(j.row, j.param): i for i, j in enumerate(boom.joints)}
    out: list[tuple[str, str, float | None, int | None]] = []

    def add(kind: str, axis: str, value: float, row: int, param: str) -> None:
        if value:
            out.append((kind, axis, float(value), None))
        i = by_row.get((row, param))
        if i is not None:
            joint = boom.joints[i]
            if joint.locked is not None:
                if joint.locked:
                    out.append((kind, axis, float(joint.locked), None))
            else:
                out.append((kind, axis, None, i))

    for row, (alpha, a, theta, d) in enumerate(boom.rows):
        if boom.convention == "modified":
            add("R", "x", alpha, row, "alpha")
            add("t", "x", a, row, "a")
            add("R", "z", theta, row, "theta")
            add("t", "z", d, row, "d")
        else:
            add("R", "z", theta, row, "theta")
            add("t", "z", d, row, "d")
            add("t", "x", a, row, "a")
            add("R", "x", alpha, row, "alpha")
    for axis, value in zip("xyz", boom.tool, strict=True):
        if value:
            out.append(("t", axis, float(value), None))
    return out


def _elementary_matrix(kind: str, axis: str, value: float) -> np.ndarray:
    T = np.eye(4)
    k = "xyz".index(axis)
    if kind == "t":
        T[k, 3] = value
    else:
        c, s = math.cos(value), math.sin(value)
        i, j = [(1, 2), (2, 0), (0, 1)][k]
        T[i, i], T[i, j], T[j, i], T[j, j] = c, -s, s, c
    return T


def _full_turn(boom: Boom) -> np.ndarray:
    """Joints whose range spans a full turn: they wrap (as the project's solvers let them)."""
    return np.array([j.revolute and j.locked is None and j.upper - j.lower >= 2 * math.pi - 1e-9 for j in boom.joints])


def _wrap(q: np.ndarray, boom: Boom, wraps: np.ndarray) -> np.ndarray:
    lo = np.array([j.lower for j in boom.joints])
    q = q.copy()
    q[..., wraps] = np.mod(q[..., wraps] - lo[wraps], 2 * math.pi) + lo[wraps]
    return q


def hole_frames(pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Collars ``(B, 3)`` and a tool rotation ``(B, 3, 3)`` per hole whose z is the drilling
    direction (any roll: the roll is left free)."""
    p, u = pose[:, :3], pose[:, 3:] - pose[:, :3]
    u = u / np.linalg.norm(u, axis=1, keepdims=True)
    ref = np.where(np.abs(u[:, 2:3]) < 0.9, np.array([[0.0, 0.0, 1.0]]), np.array([[1.0, 0.0, 0.0]]))
    x = np.cross(ref, u)
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    y = np.cross(u, x)
    return p, np.stack([x, y, u], axis=-1)


def _home(boom: Boom) -> np.ndarray:
    lo, hi = (t.numpy() for t in boom.limits())
    return 0.5 * (lo + hi)


class PeerSolver(Solver):
    """One hole at a time (these libraries solve one pose per call), from the middle of every joint
    range, then from random joint vectors (seeded) until one converges."""

    module = ""

    def __init__(self, boom: Boom, name: str, restarts: int, seed: int):
        super().__init__(boom)
        if boom.preview_depth is None:
            raise PeersUnavailable(f"{name}: boom '{boom.name}' has no preview_depth, so holes are undefined")
        self.name, self.restarts, self.seed = name, int(restarts), int(seed)
        self.wraps = _full_turn(boom)
        self.lo, self.hi = (t.numpy().copy() for t in boom.limits())
        self.home = _home(boom)

    def starts(self, rng: np.random.Generator):
        yield self.home
        for _ in range(self.restarts):
            yield self.lo + rng.random(len(self.lo)) * (self.hi - self.lo)

    def _one(self, p: np.ndarray, R: np.ndarray, rng) -> tuple[np.ndarray, int]:
        raise NotImplementedError

    def _solve(self, targets: Targets) -> tuple[torch.Tensor, torch.Tensor]:
        if not isinstance(targets, HoleTargets):
            raise TypeError(f"{self.name}: solves holes (HoleTargets), got {type(targets).__name__}")
        p, R = hole_frames(targets.pose.detach().cpu().double().numpy())
        rng = np.random.default_rng(self.seed)
        q, iters = np.empty((len(p), self.boom.n_joints)), np.empty(len(p), dtype=np.int64)
        for i in range(len(p)):  # one pose per library call: that is how these libraries are used
            q[i], iters[i] = self._one(p[i], R[i], rng)
        q = np.clip(_wrap(q, self.boom, self.wraps), self.lo, self.hi)
        return torch.from_numpy(q), torch.from_numpy(iters)


class RoboticsToolboxSolver(PeerSolver):
    """Robotics Toolbox ``ETS.ik_LM`` (C++ Levenberg-Marquardt, Chan's damping) on the boom's chain,
    the base rotated per hole so that the mask frees the roll about the drill axis (module docstring)."""

    module = "roboticstoolbox"

    def __init__(self, boom: Boom, name: str = "rtb_ik_lm", tol: float = 1e-16, ilimit: int = 30,
                 slimit: int = 100, restarts: int = 0, seed: int = 0):
        super().__init__(boom, name, restarts, seed)
        rtb = _import(self.module)
        ET, ETS = rtb.ET, rtb.ETS
        make = {("R", "x"): ET.Rx, ("R", "y"): ET.Ry, ("R", "z"): ET.Rz,
                ("t", "x"): ET.tx, ("t", "y"): ET.ty, ("t", "z"): ET.tz}
        self.base = ET.SE3(np.eye(4))  # its rotation is set per hole
        elements = [self.base]
        for kind, axis, value, joint in elementary_chain(boom):
            if joint is None:
                elements.append(make[kind, axis](value))
            else:  # full-turn joints get room to wrap; the answer is wrapped back into the range
                j = boom.joints[joint]
                lo, hi = (j.lower - 2 * math.pi, j.upper + 2 * math.pi) if self.wraps[joint] else (j.lower, j.upper)
                elements.append(make[kind, axis](jindex=joint, qlim=[lo, hi]))
        self.ets = ETS(elements)
        self.base = self.ets.data[0]
        self.tol, self.ilimit, self.slimit = float(tol), int(ilimit), int(slimit)
        self.mask = np.array([1.0, 1.0, 1.0, 1.0, 1.0, 0.0])

    def set_base_rotation(self, R_b: np.ndarray) -> None:
        """Rotate the chain's base. The compiled ETS keeps a pointer to the base element's matrix,
        so writing it in place moves the chain without rebuilding it (1 ms a rebuild)."""
        self.base._T[:3, :3] = R_b

    def fkine(self, q: np.ndarray) -> np.ndarray:
        return np.asarray(self.ets.fkine(q).A)

    def _one(self, p, R, rng):
        R_b = R.T  # takes the drilling direction (R's z) to the base z
        self.set_base_rotation(R_b)
        target = np.eye(4)
        target[:3, 3] = R_b @ p  # in the rotated frame the tool's rotation is the identity, up to the roll
        total = 0
        for q0 in self.starts(rng):
            sol = self.ets.ik_LM(target, q0=q0, ilimit=self.ilimit, slimit=self.slimit, tol=self.tol,
                                 mask=self.mask, joint_limits=True)
            total += int(sol.iterations)
            if sol.success:
                break
        return np.asarray(sol.q, dtype=np.float64), total


class PinocchioSolver(PeerSolver):
    """Pinocchio CLIK: ``log6`` error in the tool frame less its roll row, damped Gauss-Newton steps
    ``v = -J^T (J J^T + damp I)^-1 e`` integrated with unit gain, joints projected onto their ranges."""

    module = "pinocchio"

    def __init__(self, boom: Boom, name: str = "pinocchio_clik", eps: float = 1e-10, max_iters: int = 100,
                 damp: float = 1e-12, restarts: int = 10, seed: int = 0):
        super().__init__(boom, name, restarts, seed)
        pin = self.pin = _import(self.module)
        model = pin.Model()
        joint_models = {("R", "x"): pin.JointModelRX, ("R", "y"): pin.JointModelRY, ("R", "z"): pin.JointModelRZ,
                        ("t", "x"): pin.JointModelPX, ("t", "y"): pin.JointModelPY, ("t", "z"): pin.JointModelPZ}
        parent, placement, order = 0, np.eye(4), []
        for kind, axis, value, joint in elementary_chain(boom):
            if joint is None:  # constants gather into the next joint's placement
                placement = placement @ _elementary_matrix(kind, axis, value)
                continue
            parent = model.addJoint(parent, joint_models[kind, axis](), pin.SE3(placement[:3, :3], placement[:3, 3]),
                                    boom.joints[joint].name)
            order.append(joint)
            placement = np.eye(4)
        self.frame = model.addFrame(pin.Frame("tool", parent, pin.SE3(placement[:3, :3], placement[:3, 3]),
                                              pin.FrameType.OP_FRAME))
        self.model, self.data = model, model.createData()
        self.order = np.array(order)  # pinocchio's q index k is the boom's joint order[k]
        self.free_lo, self.free_hi = self.lo[self.order], self.hi[self.order]
        self.free_wraps = self.wraps[self.order]
        self.fixed = self.home.copy()  # locked joints sit at their lock (lower == upper)
        self.eps, self.max_iters, self.damp = float(eps), int(max_iters), float(damp)

    def full(self, x: np.ndarray) -> np.ndarray:
        q = self.fixed.copy()
        q[self.order] = x
        return q

    def fkine(self, q: np.ndarray) -> np.ndarray:
        self.pin.framesForwardKinematics(self.model, self.data, np.asarray(q, dtype=np.float64)[self.order])
        return np.asarray(self.data.oMf[self.frame].homogeneous)

    def _one(self, p, R, rng):
        pin, model, data, fid = self.pin, self.model, self.data, self.frame
        goal = pin.SE3(R, p)
        eye5 = np.eye(5)
        total = 0
        best, best_err = None, math.inf
        for q0 in self.starts(rng):
            x = q0[self.order].copy()
            for _ in range(self.max_iters):
                pin.computeJointJacobians(model, data, x)  # forward kinematics and every joint's Jacobian
                pin.updateFramePlacement(model, data, fid)
                iMd = data.oMf[fid].actInv(goal)
                e = pin.log6(iMd).vector[:5]  # the tool frame's error; row 5 is the roll about the drill axis
                err = float(np.linalg.norm(e))
                if err < best_err:
                    best, best_err = x.copy(), err
                if err < self.eps:
                    break
                J = -(pin.Jlog6(iMd.inverse()) @ pin.getFrameJacobian(model, data, fid, pin.LOCAL))[:5]
                x = x - J.T @ np.linalg.solve(J @ J.T + self.damp * eye5, e)
                lo = self.free_lo
                x = np.where(self.free_wraps, np.mod(x - lo, 2 * math.pi) + lo, np.clip(x, lo, self.free_hi))
                total += 1
            if best_err < self.eps:
                break
        return self.full(best), total


PEERS = {"rtb_ik_lm": RoboticsToolboxSolver, "pinocchio_clik": PinocchioSolver}


def build_peer(kind: str, boom: Boom, **params) -> PeerSolver:
    """A peer solver by its kind (``rtb_ik_lm`` or ``pinocchio_clik``); :class:`PeersUnavailable`
    with the install line when its library is missing."""
    if kind not in PEERS:
        raise KeyError(f"peer solver kind {kind!r}: expected one of {sorted(PEERS)}")
    return PEERS[kind](boom, **params)
