"""Per-joint geometric errors of a boom in product-of-exponentials form (paper 004 eqs. 1-5).

Each D-H row ``i`` carries an error twist ``xi_i = (rx, ry, rz, tx, ty, tz)`` (rad, m) written in
the row's *axis frame* ``P_i = RotX(alpha_{i-1}) TransX(a_{i-1})``, whose z axis is joint i's
nominal axis. Paper 004's three dominant errors are components of it:

* rotation-angle error: ``rz``, a turn about the joint axis (for a revolute joint, its zero offset);
* axis tilt: ``rx, ry``, the axis turned away from its nominal direction;
* axis offset: ``tx, ty, tz``, the axis shifted (paper 004 eq. 2 translates along all three axes;
  ``tz`` of a prismatic joint is its length offset).

The erroneous row transform is ``E_i @ T_i(q)`` with ``E_i = exp(Ad_{P_i} xi_i)`` in frame i-1:
the error is pre-multiplied, so it moves joint i's axis and everything after it, and the joint
then moves about (along) its *actual* axis. For the modified convention the z axis and origin of
``frames[i]`` therefore lie on joint i's actual axis, which is what Jacobians and the safety model
read. The twist is mapped to frame i-1 by the adjoint (paper 004 eq. 4) before the exponential,
so a zero twist gives ``E_i = I`` exactly and the boom is then exactly the nominal one.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from pipeline.core.errors import ConfigError, InputError
from pipeline.geometry.kinematics import Boom
from pipeline.geometry.rotations import se3_exp

DTYPE = torch.float64
COMPONENTS = ("rx", "ry", "rz", "tx", "ty", "tz")  # twist order: rotation (rad), then translation (m)
ROTATION = (0, 1, 2)
DISTRIBUTIONS = ("sign", "normal")


@dataclass(frozen=True)
class ErrorLevel:
    """Magnitudes of the three dominant errors: rotation angle and tilt (deg), axis offset (mm)."""

    angle_deg: float
    tilt_deg: float
    offset_mm: float

    def __post_init__(self):
        for key in ("angle_deg", "tilt_deg", "offset_mm"):
            v = getattr(self, key)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
                raise ConfigError(f"calibration level.{key} = {v!r}: expected a finite number >= 0")

    def scales(self) -> torch.Tensor:
        """Per-component magnitude in SI units, in :data:`COMPONENTS` order."""
        tilt, angle, offset = math.radians(self.tilt_deg), math.radians(self.angle_deg), self.offset_mm * 1e-3
        return torch.tensor([tilt, tilt, angle, offset, offset, offset], dtype=DTYPE)


def parameter_names(boom: Boom) -> list[str]:
    """``<joint>.<component>`` for every row and component (``row<i>`` for a row no joint drives)."""
    by_row = {j.row: j.name for j in boom.joints}
    return [f"{by_row.get(r, f'row{r + 1}')}.{c}" for r in range(boom.n_rows) for c in COMPONENTS]


def check_supported(boom: Boom) -> None:
    """The error frames above need modified D-H with joints on theta or d (jumbo8's kind)."""
    if boom.convention != "modified":
        raise ConfigError(
            f"boom '{boom.name}': the error model needs the modified D-H convention (the joint axis is z of the "
            f"frame after each row), got {boom.convention!r}"
        )
    bad = [j.name for j in boom.joints if j.param == "a"]
    if bad:
        raise ConfigError(f"boom '{boom.name}': joints {bad} drive a link length 'a'; the error model supports "
                          "revolute (theta) and prismatic (d) joints only")


def draw_errors(boom: Boom, level: ErrorLevel, seed: int, distribution: str = "sign") -> torch.Tensor:
    """Error twists ``(n_rows, 6)`` for a boom, drawn from ``seed``.

    ``sign``: every component is +-its level (paper 004 eq. 2 gives each component the same size;
    the sign is drawn). ``normal``: every component is normal with the level as standard deviation.
    """
    if distribution not in DISTRIBUTIONS:
        raise ConfigError(f"calibration.error_distribution = {distribution!r}; expected one of {DISTRIBUTIONS}")
    check_supported(boom)
    g = torch.Generator().manual_seed(int(seed))
    shape = (boom.n_rows, len(COMPONENTS))
    if distribution == "sign":
        unit = torch.randint(0, 2, shape, generator=g).to(DTYPE) * 2 - 1
    else:
        unit = torch.randn(shape, generator=g, dtype=DTYPE)
    return unit * level.scales()


def axis_frames(boom: Boom, dtype=DTYPE, device=None) -> torch.Tensor:
    """``P_i = RotX(alpha_{i-1}) TransX(a_{i-1})`` per row ``(n_rows, 4, 4)``: z is joint i's nominal axis."""
    rows = torch.tensor(boom.rows, dtype=dtype, device=device)
    alpha, a = rows[:, 0], rows[:, 1]
    ca, sa = torch.cos(alpha), torch.sin(alpha)
    one, zero = torch.ones_like(ca), torch.zeros_like(ca)
    return torch.stack([
        one, zero, zero, a,
        zero, ca, -sa, zero,
        zero, sa, ca, zero,
        zero, zero, zero, one,
    ], -1).reshape(-1, 4, 4)


def error_transforms(frames_p: torch.Tensor, twists: torch.Tensor) -> torch.Tensor:
    """``E_i = exp(Ad_{P_i} xi_i)`` ``(n_rows, 4, 4)`` in frame i-1 (paper 004 eq. 4: the adjoint
    carries the twist from the axis frame to frame i-1). Differentiable in ``twists``."""
    R, p = frames_p[..., :3, :3], frames_p[..., :3, 3]
    w = (R @ twists[..., :3].unsqueeze(-1)).squeeze(-1)
    v = (R @ twists[..., 3:].unsqueeze(-1)).squeeze(-1) + torch.linalg.cross(p, w, dim=-1)
    return se3_exp(torch.cat([w, v], -1))


class BoomWithErrors(Boom):
    """A nominal boom plus error twists: FK, IK solvers and the safety model use it unchanged.

    Only :meth:`link_transforms` differs (``E_i @ T_i``); frames, tool pose, pose6 and collision
    bodies follow from it. ``twists`` is ``(n_rows, 6)`` in :data:`COMPONENTS` order (rad, m).
    """

    def __init__(self, nominal: Boom, twists: torch.Tensor):
        check_supported(nominal)
        if not isinstance(twists, torch.Tensor) or twists.shape != (nominal.n_rows, len(COMPONENTS)):
            got = tuple(twists.shape) if isinstance(twists, torch.Tensor) else type(twists).__name__
            raise InputError(f"error twists of boom '{nominal.name}': expected shape ({nominal.n_rows}, 6), got {got}")
        if not torch.isfinite(twists).all():
            raise InputError(f"error twists of boom '{nominal.name}': non-finite values")
        super().__init__(nominal.name, nominal.convention, nominal.rows, nominal.joints, nominal.tool,
                         nominal.preview_depth, tuple(nominal.bodies.values()), nominal.self_pairs)
        self.nominal = nominal
        self.twists = twists.detach().to(DTYPE).cpu().clone()
        self._errors: dict[tuple, torch.Tensor] = {}

    def error_transforms(self, dtype=DTYPE, device=None) -> torch.Tensor:
        key = (dtype, torch.device(device) if device is not None else torch.device("cpu"))
        if key not in self._errors:  # computed in float64, then cast: a float32 FK gets the same errors
            E = error_transforms(axis_frames(self.nominal), self.twists)
            self._errors[key] = E.to(dtype=dtype, device=key[1])
        return self._errors[key]

    def link_transforms(self, q: torch.Tensor) -> torch.Tensor:
        return self.error_transforms(q.dtype, q.device) @ super().link_transforms(q)
