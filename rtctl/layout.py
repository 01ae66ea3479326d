"""Named layout of the steady-state NLP (7.25): variables, parameters and constraints.

One description, read by the offline NLP builder (``offline.rover.primitives``), its bounds,
its independent check and its evidence, written into every table file, and read back by the
on-rover QP (:mod:`rtctl.allocator`). numpy and the standard library only.

Decision variables, per wheel in :data:`WHEELS` order, in :data:`WHEEL_VARIABLES` order:
``omega`` (rad/s), ``beta`` (steering = slip angle for straight driving, rad), ``W`` (load, N),
``h`` (sinkage, m), ``h0`` (zero-slip sinkage fixing theta_m0 in skid, m). The NLP works on
scaled variables ``x_scaled = x / scale``.

Parameters (in order): ``speed`` (m/s), ``slope`` (rad, pitch of the terrain along the travel
direction, (7.32)-(7.33)), ``cross_slope`` (rad, roll of the terrain, left side up positive),
``fy_offset`` (N) and ``mz_offset`` (N m) (7.26)-(7.27), ``contact <wheel>`` (1 in contact,
0 raised) and ``pivot_locked`` (1 when a raised wheel locks the rocker pivot).

Constraints (in order): the seven balance rows (force x, y, z; moment x; pitch of both rockers,
of the right rocker; moment z), then per wheel the load (7.23), the zero-slip load and the wheel
torque rows, then optional rows of a trench goal. Each row carries its scale (the NLP sees
``residual / scale``).
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from typing import Any, Sequence

import numpy as np
from numpy.typing import NDArray

__all__ = ["WHEELS", "WHEEL_VARIABLES", "BALANCE_ROWS", "PARAMETERS", "Block", "NlpLayout", "LayoutError"]

WHEELS: tuple[str, ...] = ("FR", "FL", "RR", "RL")
"""Wheel order of every per-wheel array (front right, front left, rear right, rear left; Fig. 7.2)."""
WHEEL_VARIABLES: tuple[str, ...] = ("omega", "beta", "W", "h", "h0")
"""Per-wheel decision variables of (7.25), in storage order."""
BALANCE_ROWS: tuple[str, ...] = ("Fx", "Fy", "Fz", "Mx", "My_right", "My_left", "Mz")
"""Balance residual rows (7.12)-(7.18)/(7.23), in storage order."""
PARAMETERS: tuple[str, ...] = ("speed", "slope", "cross_slope", "fy_offset", "mz_offset",
                               *(f"contact {w}" for w in WHEELS), "pivot_locked")
"""NLP parameters, in storage order."""


class LayoutError(ValueError):
    """A layout description that is inconsistent or does not match the data it describes."""


@dataclass(frozen=True)
class Block:
    """A named, contiguous run of entries (variables, parameters or constraint rows).

    Attributes
    ----------
    name : str
        For example ``"omega FR"`` or ``"balance Fx"``.
    start, stop : int
        Python slice bounds into the stacked vector.
    unit : str
        SI unit of the unscaled quantity.
    scale : float
        Typical magnitude: the NLP sees ``value / scale``.
    """

    name: str
    start: int
    stop: int
    unit: str
    scale: float

    @property
    def slice(self) -> slice:
        """``slice(start, stop)``."""
        return slice(self.start, self.stop)


@dataclass(frozen=True)
class NlpLayout:
    """Variables, parameters and constraints of one NLP instance, by name.

    Build with :meth:`build`; serialise with :meth:`to_json` / :meth:`from_json` (the table file
    stores it so the QP reads the same rows the NLP was solved with).
    """

    variables: tuple[Block, ...]
    parameters: tuple[Block, ...]
    constraints: tuple[Block, ...]
    wheels: tuple[str, ...] = WHEELS
    trench_wheel: str | None = None
    _index: dict[str, Block] = field(default_factory=dict, repr=False, compare=False)

    def __post_init__(self) -> None:
        idx: dict[str, Block] = {}
        for group in (self.variables, self.parameters, self.constraints):
            pos = 0
            for b in group:
                if b.start != pos or b.stop <= b.start:
                    raise LayoutError(f"block {b.name!r} at [{b.start}, {b.stop}) does not follow the previous one at {pos}")
                if not (np.isfinite(b.scale) and b.scale > 0):
                    raise LayoutError(f"block {b.name!r}: scale must be finite and > 0, got {b.scale}")
                if b.name in idx:
                    raise LayoutError(f"duplicate block name {b.name!r}")
                idx[b.name] = b
                pos = b.stop
        object.__setattr__(self, "_index", idx)

    # ------------------------------------------------------------------ construction
    @classmethod
    def build(cls, variable_scales: dict[str, float], constraint_scales: dict[str, float],
              trench_wheel: str | None = None, wheels: Sequence[str] = WHEELS,
              parameter_scales: dict[str, float] | None = None,
              balance_rows: Sequence[str] = BALANCE_ROWS) -> "NlpLayout":
        """The layout of (7.25) for a rover with ``wheels``.

        Parameters
        ----------
        variable_scales : dict
            Scale per wheel variable name (``omega``, ``beta``, ``W``, ``h``, ``h0``).
        constraint_scales : dict
            ``force`` (N), ``moment`` (N m), ``load`` (N), ``torque`` (N m); ``height`` (m) with
            height-compatibility balance rows; and, with a trench
            wheel, ``trench_area`` (m^2) and ``trench_length`` (m).
        trench_wheel : str, optional
            Wheel whose trench goal rows (clean-side pile, depth, flat width) are present.
        wheels : sequence of str
            Wheel names in storage order (default the mini rover's :data:`WHEELS`; a rover file's
            wheels in file order).
        parameter_scales : dict, optional
            Scales replacing the defaults of the parameters.
        balance_rows : sequence of str
            Names of the balance rows (default :data:`BALANCE_ROWS`, the four-wheel rocker's; a
            rover file's suspension gives its own,
            :attr:`rtctl.physics.suspension.SuspensionStatics.balance_names`). A row whose name
            starts with ``F`` is a force (N), any other a moment (N m).
        """
        units = {"omega": "rad/s", "beta": "rad", "W": "N", "h": "m", "h0": "m"}
        var, pos = [], 0
        for w in wheels:
            for v in WHEEL_VARIABLES:
                var.append(Block(f"{v} {w}", pos, pos + 1, units[v], float(variable_scales[v])))
                pos += 1
        ps = {"speed": 0.03, "slope": 0.1, "cross_slope": 0.1, "fy_offset": 1.0, "mz_offset": 0.1, "pivot_locked": 1.0}
        ps.update(parameter_scales or {})
        punits = {"speed": "m/s", "slope": "rad", "cross_slope": "rad", "fy_offset": "N", "mz_offset": "N m"}
        par = []
        names = ["speed", "slope", "cross_slope", "fy_offset", "mz_offset", *(f"contact {w}" for w in wheels), "pivot_locked"]
        for i, n in enumerate(names):
            par.append(Block(n, i, i + 1, punits.get(n, "1"), float(ps.get(n, 1.0))))
        con, pos = [], 0

        def add(name: str, unit: str, scale: float) -> None:
            nonlocal pos
            con.append(Block(name, pos, pos + 1, unit, float(scale)))
            pos += 1

        for r in balance_rows:
            if r.startswith("height_compatibility"):  # a rigid frame's wheel heights on one plane, m
                add(f"balance {r}", "m", constraint_scales["height"])
                continue
            force = r.startswith("F")
            add(f"balance {r}", "N" if force else "N m", constraint_scales["force" if force else "moment"])
        for kind, unit, key in (("load", "N", "load"), ("zero-slip load", "N", "load"), ("wheel torque", "N m", "torque")):
            for w in wheels:
                add(f"{kind} {w}", unit, constraint_scales[key])
        if trench_wheel is not None:
            if trench_wheel not in wheels:
                raise LayoutError(f"trench wheel {trench_wheel!r} is not one of {tuple(wheels)}")
            add(f"trench clean-side pile {trench_wheel}", "m^2", constraint_scales["trench_area"])
            add(f"trench depth {trench_wheel}", "m", constraint_scales["trench_length"])
            add(f"trench flat width {trench_wheel}", "m", constraint_scales["trench_length"])
        return cls(tuple(var), tuple(par), tuple(con), tuple(wheels), trench_wheel)

    # ------------------------------------------------------------------ lookup
    @property
    def nx(self) -> int:
        """Number of decision variables."""
        return self.variables[-1].stop

    @property
    def np_(self) -> int:
        """Number of parameters."""
        return self.parameters[-1].stop

    @property
    def ng(self) -> int:
        """Number of constraint rows."""
        return self.constraints[-1].stop

    def __getitem__(self, name: str) -> Block:
        try:
            return self._index[name]
        except KeyError:
            raise LayoutError(f"no block named {name!r}; known: {sorted(self._index)[:12]} ...") from None

    def index(self, name: str) -> int:
        """Position of a one-entry block (variable, parameter or constraint) in its vector."""
        return self[name].start

    def var(self, variable: str, wheel: str) -> int:
        """Position of ``variable`` (``omega``, ``beta``, ``W``, ``h``, ``h0``) of ``wheel``."""
        return self.index(f"{variable} {wheel}")

    def wheel_slice(self, wheel: str) -> slice:
        """The five variables of one wheel."""
        i = self.wheels.index(wheel) * len(WHEEL_VARIABLES)
        return slice(i, i + len(WHEEL_VARIABLES))

    def rows(self, prefix: str) -> list[int]:
        """Constraint rows whose name starts with ``prefix`` (e.g. ``"balance"``, ``"load "``)."""
        return [b.start for b in self.constraints if b.name.startswith(prefix)]

    @property
    def variable_scale(self) -> NDArray[np.float64]:
        """Scale of every variable (``x = x_scaled * variable_scale``)."""
        return np.array([b.scale for b in self.variables])

    @property
    def constraint_scale(self) -> NDArray[np.float64]:
        """Scale of every constraint row (the NLP sees ``residual / constraint_scale``)."""
        return np.array([b.scale for b in self.constraints])

    @property
    def variable_names(self) -> list[str]:
        """Variable names in storage order."""
        return [b.name for b in self.variables]

    @property
    def parameter_names(self) -> list[str]:
        """Parameter names in storage order."""
        return [b.name for b in self.parameters]

    @property
    def constraint_names(self) -> list[str]:
        """Constraint row names in storage order."""
        return [b.name for b in self.constraints]

    # ------------------------------------------------------------------ serialisation
    def to_json(self) -> str:
        """Canonical JSON (sorted keys): the same layout always gives the same text."""
        d: dict[str, Any] = {
            "wheels": list(self.wheels),
            "trench_wheel": self.trench_wheel,
            "variables": [asdict(b) for b in self.variables],
            "parameters": [asdict(b) for b in self.parameters],
            "constraints": [asdict(b) for b in self.constraints],
        }
        return json.dumps(d, sort_keys=True, separators=(",", ":"))

    @classmethod
    def from_json(cls, text: str) -> "NlpLayout":
        """Inverse of :meth:`to_json`; raises :class:`LayoutError` on a malformed description."""
        try:
            d = json.loads(text)
            blocks = {k: tuple(Block(**b) for b in d[k]) for k in ("variables", "parameters", "constraints")}
            return cls(blocks["variables"], blocks["parameters"], blocks["constraints"], tuple(d["wheels"]), d["trench_wheel"])
        except (KeyError, TypeError, json.JSONDecodeError) as exc:
            raise LayoutError(f"malformed NLP layout description: {exc}") from exc
