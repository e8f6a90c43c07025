"""Where each parameter sits in the parameter vector of a whole-robot fit.

The vector is laid out in blocks, in this order:

* ``a``: the six base points, (6, 3) mm, row-major (a1.x, a1.y, a1.z, a2.x, …), columns 0–17;
* ``b``: the six platform points, (6, 3) mm, the same way, columns 18–35;
* ``offsets``: the six leg offsets, (6,) mm, columns 36–41 — only when they are fitted
  (Model 42); Model 36 keeps them fixed at the drawing's and leaves the block out;
* ``effects``: the effect parameters θ, (q,), in the units of their specs, after the above.

A fit with clamp rows (:mod:`hexcal.estimate.clamp_rows`) appends the steps' nuisance unknowns
after :attr:`ParameterLayout.size`; the blocks here are unchanged by them. The same indices
number the columns of the fit's Jacobian and the rows and columns of its covariance.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TypeVar

import numpy as np

#: Legs of the platform, and coordinates per point.
LEGS = 6
_XYZ = 3
#: Base and platform points together: 2 × 6 × 3 coordinates, mm.
_N_POINTS = 2 * LEGS * _XYZ
#: A leg index (0-based) or an integer array of them; a column index comes back alike.
_Index = TypeVar("_Index", int, np.ndarray)


@dataclass(frozen=True)
class ParameterLayout:
    """The blocks of a whole-robot parameter vector: a and b (6, 3) mm, the offsets (6,) mm when
    ``fit_offsets`` (Model 42), then ``n_effects`` effect parameters.

    The accessors return views of the vector (no copy), exactly as slicing by hand would.
    """

    fit_offsets: bool
    n_effects: int = 0

    def __post_init__(self) -> None:
        if self.n_effects < 0:
            raise ValueError(f"n_effects must be ≥ 0, not {self.n_effects}")

    @classmethod
    def for_model(cls, model: int, n_effects: int = 0) -> ParameterLayout:
        """The layout of Model 36 (offsets fixed) or Model 42 (offsets fitted)."""
        if model not in (36, 42):
            raise ValueError(f"model must be 36 or 42, not {model}")
        return cls(model == 42, n_effects)

    @classmethod
    def of_vector(cls, x: np.ndarray, fit_offsets: bool) -> ParameterLayout:
        """The layout of a vector ``x`` whose tail after the geometry is all effect parameters
        (the vector a :class:`~hexcal.estimate.refine.Refinement` reports)."""
        n = len(x) - (_N_POINTS + (LEGS if fit_offsets else 0))
        if n < 0:
            raise ValueError(f"a vector of {len(x)} is shorter than the geometry's")
        return cls(fit_offsets, n)

    # -- sizes and slices ------------------------------------------------------------------

    @property
    def n_geometry(self) -> int:
        """Parameters before the effects: a and b (36), plus the offsets when fitted (42)."""
        return _N_POINTS + (LEGS if self.fit_offsets else 0)

    @property
    def size(self) -> int:
        """Length of the vector: :attr:`n_geometry` + :attr:`n_effects`."""
        return self.n_geometry + self.n_effects

    @property
    def a_slice(self) -> slice:
        """The base points' block, columns 0–17."""
        return slice(0, LEGS * _XYZ)

    @property
    def b_slice(self) -> slice:
        """The platform points' block, columns 18–35."""
        return slice(LEGS * _XYZ, _N_POINTS)

    @property
    def offsets_slice(self) -> slice:
        """The leg offsets' block, columns 36–41; an error when they are not fitted."""
        if not self.fit_offsets:
            raise ValueError("this layout does not fit the leg offsets (Model 36)")
        start = _N_POINTS
        return slice(start, start + LEGS)

    @property
    def geometry_slice(self) -> slice:
        """a, b and the offsets when fitted: columns 0 to :attr:`n_geometry`."""
        return slice(0, self.n_geometry)

    @property
    def effects_slice(self) -> slice:
        """The effect parameters' block, after the geometry."""
        return slice(self.n_geometry, self.size)

    def blocks(self) -> dict[str, slice]:
        """``{"a", "b", ["offsets"], ["effects"]}`` → slice, the blocks present, in order."""
        out = {"a": self.a_slice, "b": self.b_slice}
        if self.fit_offsets:
            out["offsets"] = self.offsets_slice
        if self.n_effects:
            out["effects"] = self.effects_slice
        return out

    # -- per-leg columns (ints or integer arrays of leg indices, 0-based) -------------------

    def a_column(self, leg: _Index, axis: int) -> _Index:
        """Column of coordinate ``axis`` (0–2: x, y, z) of base point ``leg`` (0–5)."""
        return _XYZ * leg + axis

    def b_column(self, leg: _Index, axis: int) -> _Index:
        """Column of coordinate ``axis`` (0–2) of platform point ``leg`` (0–5)."""
        return LEGS * _XYZ + _XYZ * leg + axis

    def offset_column(self, leg: _Index) -> _Index:
        """Column of leg ``leg``'s (0–5) offset; an error when the offsets are not fitted."""
        return self.offsets_slice.start + leg

    def a_of_leg(self, leg: int) -> slice:
        """Columns of base point ``leg`` (0–5): its x, y, z."""
        return slice(_XYZ * leg, _XYZ * leg + _XYZ)

    def b_of_leg(self, leg: int) -> slice:
        """Columns of platform point ``leg`` (0–5): its x, y, z."""
        start = LEGS * _XYZ + _XYZ * leg
        return slice(start, start + _XYZ)

    # -- views and packing -----------------------------------------------------------------

    def a(self, x: np.ndarray) -> np.ndarray:
        """The base points (6, 3) mm: a view of ``x``'s (or of a batch's, (..., p)) block."""
        return x[..., self.a_slice].reshape(*x.shape[:-1], LEGS, _XYZ)

    def b(self, x: np.ndarray) -> np.ndarray:
        """The platform points (6, 3) mm: a view of ``x``'s block."""
        return x[..., self.b_slice].reshape(*x.shape[:-1], LEGS, _XYZ)

    def offsets(self, x: np.ndarray, fixed: np.ndarray | None = None) -> np.ndarray:
        """The leg offsets (6,) mm: ``x``'s block when fitted, else ``fixed`` (the drawing's,
        (6,) mm, returned as given; required then)."""
        if self.fit_offsets:
            return x[..., self.offsets_slice]
        if fixed is None:
            raise ValueError("the offsets are not fitted (Model 36): pass the fixed ones")
        return fixed

    def effects(self, x: np.ndarray) -> np.ndarray:
        """The effect parameters θ (q,): a view of ``x``'s block (empty without effects)."""
        return x[..., self.effects_slice]

    def pack(
        self,
        a: np.ndarray,
        b: np.ndarray,
        offsets: np.ndarray | None = None,
        effects: np.ndarray | None = None,
    ) -> np.ndarray:
        """The vector (:attr:`size`,) of a, b (6, 3) mm, the offsets (6,) mm (required when
        fitted; left out, even if given, when not) and the effect parameters (q,) (zeros when
        None)."""
        parts = [np.ravel(a), np.ravel(b)]
        if parts[0].size != LEGS * _XYZ or parts[1].size != LEGS * _XYZ:
            raise ValueError(f"a and b must be (6, 3), not {np.shape(a)} and {np.shape(b)}")
        if self.fit_offsets:
            if offsets is None or np.size(offsets) != LEGS:
                raise ValueError("this layout fits the leg offsets: pass them, (6,) mm")
            parts.append(np.asarray(offsets))
        theta = np.zeros(self.n_effects) if effects is None else np.asarray(effects)
        if theta.size != self.n_effects:
            raise ValueError(f"{self.n_effects} effect parameters expected, not {theta.size}")
        return np.concatenate([*parts, theta])

    def names(self, effect_names: list[str] | None = None) -> list[str]:
        """a1.x … a6.z, b1.x … b6.z, offset1 … offset6 when fitted, then ``effect_names``
        (``theta0`` … when None or empty)."""
        out = [f"a{k}.{c}" for k in range(1, LEGS + 1) for c in "xyz"]
        out += [f"b{k}.{c}" for k in range(1, LEGS + 1) for c in "xyz"]
        if self.fit_offsets:
            out += [f"offset{k}" for k in range(1, LEGS + 1)]
        if not effect_names:
            effect_names = [f"theta{i}" for i in range(self.n_effects)]
        return out + list(effect_names)
