"""Everything a leg's length error can physically follow, computed at every pose: the
covariates of the diagnosis' explorer (:mod:`hexcal.diagnosis.explorer`) and of the effects it
writes (:class:`hexcal.effects.explored.ExploredEffect`), in one place so that an effect file
loaded unedited evaluates exactly the quantity the explorer scored.

Each covariate is an (M, 6) array — a value per pose and leg; a quantity of the pose (the
platform's yaw, the time) is the same for the six legs. The library (:func:`library`):

- the platform's position ``x``, ``y``, ``z`` (mm, from the drawing's home) and orientation
  ``roll``, ``pitch``, ``yaw`` (deg, XYZ angles of the rotation from home) and ``tilt`` (deg,
  the angle of the platform's normal from its normal at home);
- the leg's own ``stroke`` (its reading, mm) and every other leg's (``stroke_leg1`` …
  ``stroke_leg6``: cross-talk, a cable or a supply shared with another leg);
- the leg's direction: ``inclination`` from the vertical and ``azimuth`` about it (deg, from
  its azimuth at home);
- the static axial ``force`` holding the platform's weight (N), and its products with the
  stroke (``force_x_stroke``, N·mm) and with the length squared (``force_x_length2``, N·m²:
  a leg bending under its load);
- the leg's turn about its base and platform joints' fixed axes (``base_joint``,
  ``platform_joint``, deg from home; robot.json's ``ujoint_axes`` and ``balljoint_axes``, their
  defaults where not stated);
- the direction of the leg's last move (``last_move``, ±1) and of the platform's along each
  axis (``platform_move_x`` … ``_z``);
- ``time`` (s from the session's start), ``temperature`` (°C) and the place in the procedure
  (``pose_index``, the pose's rank in recording order; ``step_time``, s since the pose's
  procedure step began: a clamp that settles, a structure that relaxes after each step);
- every extra numeric column of the measurement table, by its own name (a second
  thermometer, humidity, a motor current): a lab's own sensor is a covariate without code;
- the temperature and every such column seen through a first-order lag (``NAME~lagTs``,
  :mod:`hexcal.effects.lagged`): a part that follows the sensor slowly;
- the product of two of them (``A*B``, :mod:`hexcal.effects.interactions`): an error along one
  whose size changes with the other. The explorer builds these from its leads, not the library.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from hexcal.effects.backlash import deadband_mm, motion_state
from hexcal.effects.base import EffectData
from hexcal.effects.compliance import leg_forces
from hexcal.effects.interactions import SEP, parse_product, product_name
from hexcal.effects.lagged import first_order_lag, lag_name, lag_taus, parse_lag

#: A user column is a covariate when it changes by more than this share of its mean magnitude
#: (a constant column, or one that only rounds, carries nothing).
MIN_COLUMN_SPREAD = 1e-9
#: K, a change of the temperature below this is a thermometer's jitter, not a warming or a
#: cooling (a PT100's repeatability is some 0.01 K).
TEMPERATURE_JITTER_K = 0.02


@dataclass(frozen=True)
class Covariate:
    """One quantity the residual may follow: its name (the CLI's, the JSON's and the effect
    file's), what it is, its unit, the physics it points at, and how it is computed."""

    name: str
    label: str
    unit: str
    points_at: str
    values: Callable[[EffectData], np.ndarray]  #: (M, 6)
    uses_geometry: bool = False  #: evaluated at the fitted geometry
    discrete: bool = False  #: a sign itself: one shape only
    signed: bool = False  #: its sign means something (a load that reverses)
    periodic: bool = False  #: a periodic error along it is physical (a scale, a screw, a cycle)
    per_pose: bool = False  #: the same value for the six legs (a quantity of the pose)
    default_keys: tuple[str, ...] = ()  #: robot.json keys whose defaults its values rest on


def _unit(data: EffectData) -> np.ndarray:
    v = data.leg_vectors
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _per_pose(values: np.ndarray) -> np.ndarray:
    return np.repeat(np.asarray(values, float)[:, None], 6, axis=1)


def _home_rotation(data: EffectData) -> Rotation:
    q = np.asarray(data.robot.home.quaternion, float)  # scalar first
    return Rotation.from_quat(np.r_[q[1:], q[0]])


def _relative_rotation(data: EffectData) -> Rotation:
    """The platform's rotation from its home orientation, in the home frame."""
    return _home_rotation(data).inv() * Rotation.from_matrix(data.rotation)


def _angles(data: EffectData) -> np.ndarray:
    """(M, 3) deg: roll, pitch, yaw, XYZ angles of the rotation from home."""
    return _relative_rotation(data).as_euler("xyz", degrees=True)


def _tilt(data: EffectData) -> np.ndarray:
    home_z = _home_rotation(data).as_matrix()[:, 2]
    z = data.rotation[:, :, 2]
    return np.degrees(np.arccos(np.clip(z @ home_z, -1.0, 1.0)))


def _position(axis: int) -> Callable[[EffectData], np.ndarray]:
    def values(data: EffectData) -> np.ndarray:
        home = np.asarray(data.robot.home.position, float)
        return _per_pose(data.position[:, axis] - home[axis])

    return values


def _angle(axis: int) -> Callable[[EffectData], np.ndarray]:
    return lambda data: _per_pose(_angles(data)[:, axis])


def _stroke_of(leg: int) -> Callable[[EffectData], np.ndarray]:
    return lambda data: _per_pose(np.asarray(data.readings, float)[:, leg - 1])


def _inclination(data: EffectData) -> np.ndarray:
    return np.degrees(np.arccos(np.clip(_unit(data)[..., 2], -1.0, 1.0)))


def _azimuth(data: EffectData) -> np.ndarray:
    """(M, 6) deg, each leg's azimuth about the vertical from its azimuth at the home pose
    (wrapped to ±180°: a leg's azimuth swings through tens of degrees, never a turn)."""
    n = _unit(data)
    az = np.arctan2(n[..., 1], n[..., 0])
    home = np.asarray(data.robot.home.position, float)
    hv = home + _home_rotation(data).apply(data.b) - data.a
    ref = np.arctan2(hv[:, 1], hv[:, 0])
    return np.degrees(np.angle(np.exp(1j * (az - ref))))


def _joint_angle(platform: bool) -> Callable[[EffectData], np.ndarray]:
    """(M, 6) deg: each leg's turn about its joint's fixed axis from its direction at home —
    the base U-joint's (robot.json ``ujoint_axes``) or the platform joint's
    (``balljoint_axes``, in the platform frame), their defaults where not stated."""

    def values(data: EffectData) -> np.ndarray:
        from hexcal.effects.joint_axes import base_axes, home_legs, platform_axes

        n = _unit(data)
        n0, rot = home_legs(data.robot, data.a, data.b)
        if platform:
            u = platform_axes(data.robot, data.a, data.b)
            n = np.einsum("mji,mkj->mki", data.rotation, n)  # into the platform frame
            n0 = n0 @ rot
        else:
            u = base_axes(data.robot, data.a, data.b)
        p = n - np.einsum("mki,ki->mk", n, u)[..., None] * u
        p0 = n0 - np.einsum("ki,ki->k", n0, u)[:, None] * u
        sin = np.einsum("ki,mki->mk", u, np.cross(p0, p))
        cos = np.einsum("ki,mki->mk", p0, p)
        return np.degrees(np.arctan2(sin, cos))

    return values


def _platform_move(axis: int) -> Callable[[EffectData], np.ndarray]:
    """±1: the sign of the platform's last move along ``axis`` (a change under 0.01 mm is
    jitter, not a move); 0 until it first moves."""

    def values(data: EffectData) -> np.ndarray:
        pos = np.asarray(data.position, float)[:, axis : axis + 1]
        return _per_pose(motion_state(pos, 0.01)[:, 0])

    return values


def _platform_turn(axis: int) -> Callable[[EffectData], np.ndarray]:
    """±1: the sign of the platform's last turn in roll, pitch or yaw (``axis`` 0–2, the
    angles from home; a change under 0.005° is the tracker's jitter, not a turn); 0 until it
    first turns."""

    def values(data: EffectData) -> np.ndarray:
        angle = _angles(data)[:, axis : axis + 1]
        return _per_pose(motion_state(angle, 0.005)[:, 0])

    return values


def _force(data: EffectData) -> np.ndarray:
    mass = data.robot.platform_mass_kg or 1.0
    com = getattr(data.robot, "platform_com_mm", None)
    return leg_forces(data, mass, None if com is None else np.asarray(com, float))


def _force_change(data: EffectData) -> np.ndarray:
    """(M, 6) ±1: whether each leg's axial force last rose or fell (a change under 0.1 % of
    its range over the session is no change); 0 until it first changes."""
    f = _force(data)
    return motion_state(f, 1e-3 * max(float(np.max(np.ptp(f, axis=0))), 1e-12))


def _temperature_change(data: EffectData) -> np.ndarray:
    """(M, 6) ±1: whether the structure was last warming or cooling (a change under
    :data:`TEMPERATURE_JITTER_K` is a thermometer's jitter); 0 until it first changes."""
    t = np.asarray(data.temperature, float)[:, None]
    return _per_pose(motion_state(t, TEMPERATURE_JITTER_K)[:, 0])


def _force_x_stroke(data: EffectData) -> np.ndarray:
    return _force(data) * np.asarray(data.readings, float)


def _force_x_length2(data: EffectData) -> np.ndarray:
    return _force(data) * (data.lengths / 1000.0) ** 2


def _step_time(data: EffectData) -> np.ndarray:
    """(M,) s since the first pose of each pose's procedure step, in recording order; a step
    begins anew wherever the step changes from one pose to the next (poses from no procedure,
    ``data.step`` None, are one step)."""
    t = np.asarray(data.t, float)
    if data.step is None or len(t) == 0:
        return t - (float(t[0]) if len(t) else 0.0)
    step = np.asarray(data.step, dtype=object)
    start = np.r_[True, step[1:] != step[:-1]]
    first = np.maximum.accumulate(np.where(start, np.arange(len(t)), 0))
    return t - t[first]


_STROKE_PHYSICS = (
    "an encoder scale that bends or repeats along the stroke, a dent or a worn stretch of a "
    "screw or a rail"
)

#: The library's fixed covariates, in the order the report lists them.
FIXED: tuple[Covariate, ...] = (
    Covariate("stroke", "position along the stroke (the reading)", "mm", _STROKE_PHYSICS,
              lambda d: np.asarray(d.readings, float), periodic=True),
    *(
        Covariate(f"stroke_leg{j}", f"leg {j}'s stroke (its reading)", "mm",
                  f"cross-talk: something shared with leg {j} (a cable, a supply, a frame that "
                  "flexes as it moves)", _stroke_of(j), periodic=True, per_pose=True)
        for j in range(1, 7)
    ),
    *(
        Covariate(axis, f"platform position {axis} (from home)", "mm",
                  f"something the platform drags or pulls as it moves along {axis} (a cable, "
                  "a hose, a tracker's field distortion)", _position(i), per_pose=True)
        for i, axis in enumerate("xyz")
    ),
    *(
        Covariate(name, f"platform {name} (from home)", "deg",
                  f"something that follows the platform's {name} (an encoder cable dragged "
                  "as it turns, a joint that binds at an angle)", _angle(i), per_pose=True,
                  periodic=True)
        for i, name in enumerate(("roll", "pitch", "yaw"))
    ),
    Covariate("tilt", "platform tilt (from its normal at home)", "deg",
              "something that grows as the platform tilts (a joint near its limit, a bearing "
              "loaded sideways)", lambda d: _per_pose(_tilt(d)), per_pose=True),
    Covariate("inclination", "leg inclination from the vertical", "deg",
              "a leg sagging or bending under its own weight, a joint seating with the leg's "
              "angle", _inclination, uses_geometry=True),
    Covariate("azimuth", "leg azimuth about the vertical (from home)", "deg",
              "a joint or an encoder head that reads with the leg's azimuth (joint play, a "
              "cable pull)", _azimuth, uses_geometry=True, periodic=True),
    Covariate("base_joint", "leg's turn about its base joint's fixed axis (from home)", "deg",
              "a U-joint that binds, wears or reads with its angle (a joint near its limit, a "
              "bent cross)", _joint_angle(False), uses_geometry=True,
              default_keys=("ujoint_axes",)),
    Covariate("platform_joint", "leg's turn about its platform joint's axis (from home)", "deg",
              "a platform joint that binds, wears or reads with its angle", _joint_angle(True),
              uses_geometry=True, default_keys=("balljoint_axes",)),
    Covariate("force", "axial leg force holding the platform's weight", "N",
              "a leg or a joint that yields non-linearly under load", _force,
              uses_geometry=True, signed=True, default_keys=("platform_com_mm",)),
    Covariate("force_x_stroke", "axial force × stroke", "N·mm",
              "a leg whose stiffness falls as it extends (a screw loaded over its free length)",
              _force_x_stroke, uses_geometry=True, default_keys=("platform_com_mm",)),
    Covariate("force_x_length2", "axial force × length²", "N·m²",
              "a leg bending under its load (buckling-like shortening ∝ F·L²)",
              _force_x_length2, uses_geometry=True, default_keys=("platform_com_mm",)),
    Covariate("force_change", "whether the leg's axial force last rose or fell", "±1",
              "friction in a joint or a load-dependent part that holds the last load: the error "
              "depends on whether the load was rising or falling", _force_change,
              discrete=True, uses_geometry=True, default_keys=("platform_com_mm",)),
    Covariate("last_move", "direction of the leg's last move", "±1",
              "play or friction that depends on the direction of approach",
              lambda d: motion_state(d.readings, deadband_mm(d)), discrete=True),
    *(
        Covariate(f"platform_move_{axis}", f"direction of the platform's last move along {axis}",
                  "±1", "play or friction in the platform's guidance, taken up as it reverses",
                  _platform_move(i), discrete=True, per_pose=True)
        for i, axis in enumerate("xyz")
    ),
    *(
        Covariate(f"platform_move_{name}", f"direction of the platform's last turn in {name}",
                  "±1", "play or friction in a joint or a cable that the platform's turn takes "
                  "up, one way or the other as it reverses", _platform_turn(i), discrete=True,
                  per_pose=True)
        for i, name in enumerate(("roll", "pitch", "yaw"))
    ),
    Covariate("temperature", "structure temperature", "°C",
              "an expansion that is not proportional to the leg length (an encoder, a mount)",
              lambda d: _per_pose(np.asarray(d.temperature, float)), per_pose=True),
    Covariate("temperature_change", "whether the structure was last warming or cooling", "±1",
              "thermal hysteresis: a part that expands differently warming and cooling, or "
              "lags its thermometer", _temperature_change, discrete=True, per_pose=True),
    Covariate("time", "time since the session started", "s",
              "something changing during the session (warm-up, a slipping mount, an encoder "
              "drifting)", lambda d: _per_pose(np.asarray(d.t, float) - float(np.min(d.t))),
              periodic=True, per_pose=True),
    Covariate("step_time", "time since the pose's procedure step began", "s",
              "something that settles anew in every step (a clamp seating, a leg relaxing "
              "after it is clamped or released, a structure warmed by the last step's moves)",
              lambda d: _per_pose(_step_time(d)), per_pose=True),
    Covariate("pose_index", "place in the procedure (the pose's rank)", "",
              "something that changes with the procedure's course (a step's clamp, wear, the "
              "order the poses were taken in)",
              lambda d: _per_pose(np.arange(len(d), dtype=float)), per_pose=True),
)  # fmt: skip


def _column(name: str) -> Callable[[EffectData], np.ndarray]:
    return lambda data: _per_pose(data.columns[name])


def column_covariate(name: str) -> Covariate:
    """The covariate of the measurement table's extra numeric column ``name``."""
    return Covariate(
        name,
        f"the table's column {name}",
        "",
        f"whatever the lab's own sensor {name!r} measures",
        _column(name),
        per_pose=True,
    )


def _series(name: str, data: EffectData) -> np.ndarray:
    if name == "temperature":
        if data.temperature is None:
            raise ValueError("no temperature: the measurements have no temperature column")
        return np.asarray(data.temperature, float)
    return np.asarray(data.columns[name], float)


def lagged_covariate(base: str, tau_s: float) -> Covariate:
    """``base`` (the temperature or a table column) through a lag of ``tau_s`` s."""
    name = lag_name(base, tau_s)
    tau = float(max(round(tau_s), 1))  # the name's whole seconds
    return Covariate(
        name,
        f"{base} seen through a lag of {tau:g} s",
        "°C" if base == "temperature" else "",
        f"a part that follows {base} slowly (its own time to warm, to settle)",
        lambda d: _per_pose(first_order_lag(_series(base, d), np.asarray(d.t, float), tau)),
        per_pose=True,
    )


def library(data: EffectData | None = None) -> tuple[Covariate, ...]:
    """The fixed covariates, then one per extra numeric column of ``data`` (in table order),
    then the temperature and each column through each lag tried (:mod:`hexcal.effects.lagged`)."""
    names = tuple(data.columns) if data is not None else ()
    cols = tuple(column_covariate(n) for n in names)
    if data is None:
        return FIXED + cols
    series = (("temperature",) if data.temperature is not None else ()) + names
    taus = lag_taus(np.asarray(data.t, float))
    lags = tuple(lagged_covariate(b, tau) for b in series for tau in taus)
    return FIXED + cols + lags


def product_covariate(a: Covariate, b: Covariate) -> Covariate:
    """The product of the covariates ``a`` and ``b`` ((M, 6), in ``a``'s unit × ``b``'s):
    what the error follows when its size along one changes with the other. Its two factors,
    which the ``product`` shape needs apart, are :func:`covariate_factors`."""
    unit = "·".join(u for u in (a.unit, b.unit) if u)
    return Covariate(
        product_name(a.name, b.name),
        f"{a.label} × {b.label}",
        unit,
        f"an error along the {a.label} whose size changes with the {b.label} (or the other way "
        f"round): {a.points_at}, acting with {b.points_at}",
        lambda d: np.asarray(a.values(d), float) * np.asarray(b.values(d), float),
        uses_geometry=a.uses_geometry or b.uses_geometry,
        per_pose=a.per_pose and b.per_pose,
        default_keys=tuple(dict.fromkeys(a.default_keys + b.default_keys)),
    )


def covariate_factors(name: str, data: EffectData) -> np.ndarray:
    """(M, 6, 2) the two covariates of the product covariate ``name`` (``A*B``) at ``data``'s
    poses, ``A`` then ``B``."""
    pair = parse_product(name)
    if pair is None:
        raise ValueError(f"{name!r} is not a product of two covariates (A{SEP}B)")
    return np.stack([covariate_values(n, data) for n in pair], axis=-1)


def covariate(name: str, data: EffectData | None = None) -> Covariate:
    """The covariate called ``name`` (a fixed one, an extra column of ``data``, either
    through a lag: ``NAME~lagTs``, or the product of two: ``A*B``)."""
    pair = parse_product(name)
    if pair is not None:
        return product_covariate(covariate(pair[0], data), covariate(pair[1], data))
    for c in FIXED:
        if c.name == name:
            return c
    lag = parse_lag(name)
    if lag is not None:
        base, tau = lag
        if data is not None and base != "temperature" and base not in data.columns:
            raise ValueError(
                f"no covariate {name!r}: {base!r} is neither the temperature nor a numeric "
                "column of the measurements"
            )
        return lagged_covariate(base, tau)
    if data is not None and name not in data.columns:
        raise ValueError(
            f"no covariate {name!r}: neither in the library "
            f"({', '.join(c.name for c in FIXED)}) nor a numeric column of the measurements"
        )
    return column_covariate(name)


def covariate_values(name: str, data: EffectData) -> np.ndarray:
    """(M, 6) the covariate ``name`` at ``data``'s poses (its unit: :func:`covariate`)."""
    return np.asarray(covariate(name, data).values(data), float)


def numeric_columns(extra: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """The extra columns of a measurement table (text, (M,) each) that are numbers at every
    pose and change, as (M,) floats: a lab's own sensors."""
    out = {}
    for name, texts in extra.items():
        try:
            values = np.array([float(v) for v in texts], float)
        except (TypeError, ValueError):
            continue
        if values.size and np.all(np.isfinite(values)):
            scale = max(float(np.max(np.abs(values))), 1e-300)
            if np.ptp(values) > MIN_COLUMN_SPREAD * scale:
                out[name] = values
    return out
