"""``hexcal demo``: a whole calibration on mock hardware, headless, with a scripted operator.

A simulated robot is built as a real one would be (the left-hand design with its points off by
a few tenths of a millimetre and its offsets by up to a millimetre) and hides one effect of the
diagnosis catalogue at a realistic size. The mock rig serves it through the real drivers; the
scripted operator runs a procedure (clamps each leg, moves, records) into a session file saved
after every pose; then Model 42 is calibrated, the diagnosis names what is missing, the effect
is added and the error falls. The result says how close each step came to the simulator's
truth, so anyone can check it.
"""

from __future__ import annotations

import re
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from hexcal.estimate.quantiles import chi2_sf
from hexcal.io import advice
from hexcal.vocabulary import names_an_addition

if TYPE_CHECKING:
    from hexcal.procedure.session import SessionFile
    from hexcal.procedure.steps import Procedure

#: Effects the demo may hide: those the mock rig can produce and the session can reveal.
#: Not thermal: the rig has no temperature sensor yet. Not compliance: the mock's length clamp
#: holds the geometric length, so a compliant leg's encoder drifts with the load by c·ΔF (tens of
#: µm) and the clamp check (±0.02 mm) takes it for a slipping clamp.
DEMO_EFFECTS = ("gain", "backlash", "leadscrew")


@dataclass
class DemoSettings:
    """``effect`` None: drawn from :data:`DEMO_EFFECTS` by ``seed``. ``poses_per_step`` None:
    the procedure's recommended counts. ``window_s``: the still window per pose."""

    seed: int = 1
    effect: str | None = None
    effect_scale: float = 1.0
    procedure: str = "model42-direction-length"
    poses_per_step: int | None = None
    free_poses: int | None = None
    window_s: float = 0.25
    session_path: Path | None = None
    #: The rig's noise and motion (None: ``seed``); another value records a second session of
    #: the same robot, to validate a calibration on.
    rig_seed: int | None = None


def truth_vector(names: list[str], truth) -> np.ndarray:
    true = {f"a{k + 1}.{c}": truth.a[k, j] for k in range(6) for j, c in enumerate("xyz")}
    true |= {f"b{k + 1}.{c}": truth.b[k, j] for k in range(6) for j, c in enumerate("xyz")}
    true |= {f"offset{k + 1}": truth.offsets[k] for k in range(6)}
    return np.array([true[n] for n in names])


def against_truth(ref, truth) -> dict[str, Any]:
    """How far a refinement's geometry (a, b, offsets) is from the simulator's truth, against
    its own uncertainty: max and RMS error (mm), how many parameters lie outside their 95 %
    interval, and the Mahalanobis distance² with its χ² p-value."""
    idx = [i for i, n in enumerate(ref.names) if re.fullmatch(r"[ab]\d\.[xyz]|offset\d", n)]
    names = [ref.names[i] for i in idx]
    err = ref.x[idx] - truth_vector(names, truth)
    cov = ref.cov[np.ix_(idx, idx)]
    d2 = float(err @ np.linalg.solve(cov, err))
    return {
        "max_error_mm": float(np.abs(err).max()),
        "rms_error_mm": float(np.sqrt(np.mean(err**2))),
        "outside_95": int(np.sum(np.abs(err) > 1.96 * np.sqrt(np.diag(cov)))),
        "parameters": len(idx),
        "mahalanobis2": d2,
        "mahalanobis2_p": float(chi2_sf(d2, len(idx))),
    }


@dataclass
class HiddenRobot:
    """A simulated robot built off its drawing: the ``design`` the lab has, the ``truth``, the
    hidden ``effect`` (catalogue name), its ``values`` and the simulator ``hook`` that applies
    it."""

    design: Any
    truth: Any
    effect: str
    values: np.ndarray
    hook: Any

    def hidden(self) -> dict[str, Any]:
        """{name, values {parameter: value}} of the hidden effect."""
        from hexcal.effects import get_effect

        names = [sp.name for sp in get_effect(self.effect).params(self.truth)]
        return {"name": self.effect, "values": dict(zip(names, self.values.tolist(), strict=True))}


def hidden_robot(seed: int = 1, effect: str | None = None, scale: float = 1.0) -> HiddenRobot:
    """The left-hand design, its true robot (points off by a few tenths of a mm, offsets by up
    to a mm) and one hidden effect (``effect`` None: drawn from :data:`DEMO_EFFECTS`), all from
    ``seed``."""
    from hexcal.sim.inject import effect_hook, realistic_values
    from hexcal.sim.robots import left_hand
    from hexcal.sim.session_sim import SessionPlan, perturbed_truth

    rng = np.random.default_rng(seed)
    effect = effect or str(rng.choice(DEMO_EFFECTS))
    design = left_hand()
    truth = perturbed_truth(design, rng, SessionPlan())
    values = realistic_values(effect, rng, truth, scale)
    return HiddenRobot(design, truth, effect, values, effect_hook(effect, values, truth))


def run_demo(
    settings: DemoSettings | None = None, on_event: Callable[[str], None] = lambda m: None
) -> dict[str, Any]:
    """Run the demo; the JSON-ready result (see module docstring)."""
    from hexcal.procedure.steps import load_procedure

    st = settings or DemoSettings()
    # The procedure first: one beyond what a session holds is refused before anything else.
    proc = load_procedure(st.procedure)
    from hexcal.app.workflow import calibrate_model, diagnose_chain, model_of, session_inputs, store

    hr = hidden_robot(st.seed, st.effect, st.effect_scale)
    truth, effect = hr.truth, hr.effect

    if st.session_path is None:  # beside the operator's sessions, not in the current folder
        from hexcal.procedure.sessions_dir import sessions_dir

        folder = sessions_dir()
        folder.mkdir(parents=True, exist_ok=True)
        path = folder / f"hexcal-demo-{time.strftime('%Y%m%d-%H%M%S')}.json"
    else:
        path = st.session_path
    sf, t_record = _record_session(st, hr, proc, path, on_event)
    inp = session_inputs(sf.session, path)
    inst = inp.instruments
    if inst is None:
        raise ValueError(f"{path}: the recorded poses carry no still-window samples")
    sf.session.instruments = inst
    sf.save()
    meas = inp.meas
    on_event(f"{len(meas)} poses recorded in {t_record:.0f} s; calibrating Model {proc.model}")
    first = calibrate_model(inp, proc.model)
    store(sf, "calibration", first, meas)
    chain = diagnose_chain(inp, proc.model)
    base = chain[0]
    if names_an_addition(base.verdict):
        chain += diagnose_chain(inp, proc.model, add=[base.verdict], previous=base)
    final = model_of(inp, chain, proc.model)
    store(sf, "diagnosis", final, meas, summary=base.to_dict())
    sf.close()  # the session's lock: another program may open it now
    cal, cal_with = first.calibration, final.calibration
    return {
        "session": str(path),
        "procedure": proc.name,
        "poses": len(meas),
        "set_aside": len(sf.session.set_aside),
        "recording_s": round(t_record, 1),
        "noise_estimated": {
            "position_mm": inst.tracker.position_sigma_mm,
            "orientation_deg": inst.tracker.orientation_sigma_deg,
            "reading_mm": inst.encoders.reading_sigma_mm,
        },
        "hidden_effect": hr.hidden(),
        "calibrated": {
            "model": final.name,
            "base_points": cal_with.robot.a.tolist(),
            "platform_points": cal_with.robot.b.tolist(),
            "leg_offsets": cal_with.robot.offsets.tolist(),
            "effects": [e.model_dump() for e in final.file.calibration.effects],
        },
        "truth": {
            "base_points": truth.a.tolist(),
            "platform_points": truth.b.tolist(),
            "leg_offsets": truth.offsets.tolist(),
        },
        "diagnosis": {
            # The chain's end (none once the effect is added), the chain beside it; what the
            # first step named is what was found.
            "verdict": chain[-1].verdict,
            "chain": [d.verdict for d in chain],
            "named": base.verdict,
            "found_hidden_effect": base.verdict == effect,
            "steps": [
                {
                    "effects": [e for e in d.effects if e != "offset"],
                    "cv_rms_mm": d.fit.cv_rms_mm,
                    "noise_floor_mm": d.noise_floor_mm,
                    "verdict": d.verdict,
                }
                for d in chain
            ],
        },
        "pose_accuracy": [a.to_dict() for a in final.accuracy],
        "model_42_vs_truth": against_truth(cal.refinement, truth),
        "with_effect_vs_truth": against_truth(cal_with.refinement, truth),
        "clamps": {
            "model_42": cal.clamp_check.text if cal.clamp_check else None,
            "with_effect": cal_with.clamp_check.text if cal_with.clamp_check else None,
        },
    }


def _record_session(
    st: DemoSettings,
    hr: HiddenRobot,
    proc: Procedure,
    path: Path,
    on_event: Callable[[str], None],
) -> tuple[SessionFile, float]:
    """Record the procedure ``proc`` on a mock rig around the hidden robot into a new session
    file at ``path``: the :class:`~hexcal.procedure.session.SessionFile` and the recording's duration (s)."""
    from hexcal.acquire.acquisition import StillWindow
    from hexcal.acquire.live import open_rig
    from hexcal.app.workflow import procedure_steps
    from hexcal.mock_hw.rig import mock_rig
    from hexcal.procedure.recording import record_procedure
    from hexcal.procedure.session import Session, SessionFile

    design = hr.design
    steps = procedure_steps(proc, st.poses_per_step, st.free_poses)
    window = StillWindow(duration_s=st.window_s)
    t_start = time.monotonic()
    rig_seed = st.seed if st.rig_seed is None else st.rig_seed
    with mock_rig(hr.truth, seed=rig_seed, effects=[hr.hook]) as rig:
        sf = SessionFile.create(
            path,
            Session(robot=design, devices=rig.config, procedure=proc.model_dump(by_alias=True)),
        )
        on_event(f"session file: {path}")
        with open_rig(rig.config, window) as live:
            rig.reproducible(live.acquisition)  # the same seeds, the same session
            record_procedure(
                live.acquisition,
                rig.motion,
                steps,
                float(np.linalg.norm(design.b, axis=1).max()),
                on_event=on_event,
                on_record=sf.recording_sink(time.monotonic()),
            )
    return sf, time.monotonic() - t_start


def demo_text(r: dict[str, Any]) -> str:
    """The demo's result for a terminal."""
    d = r["diagnosis"]
    eff = r["hidden_effect"]
    vals = ", ".join(f"{k.split('.')[-1]} {v:.4g}" for k, v in eff["values"].items())
    before, after = r["model_42_vs_truth"], r["with_effect_vs_truth"]
    lines = [
        "",
        f"hexcal demo — {r['procedure']}",
        f"  {r['poses']} poses recorded through the drivers in {r['recording_s']} s "
        f"({r['set_aside']} refused or set aside, kept in {r['session']})",
        f"  hidden effect: {eff['name']} ({vals})",
        "",
        "  model                       CV RMS mm   noise floor mm   verdict",
    ]
    for st in d["steps"]:
        name = "Model 42" + "".join(f" + {e}" for e in st["effects"])
        lines.append(
            f"  {name:<27} {st['cv_rms_mm']:>9.4f}   {st['noise_floor_mm']:>14.4f}   {st['verdict']}"
        )
    found = "found it" if d["found_hidden_effect"] else f"did NOT find it (said {d['named']})"
    lines += [
        "",
        f"  the diagnosis {found}",
        "",
        "  geometry against the simulator's truth (42 parameters):",
        f"    Model 42 alone:       max error {before['max_error_mm']:.4f} mm, "
        f"{before['outside_95']} outside their 95 % interval, Mahalanobis² {before['mahalanobis2']:.1f}",
        f"    with the effect added: max error {after['max_error_mm']:.4f} mm, "
        f"{after['outside_95']} outside their 95 % interval, Mahalanobis² {after['mahalanobis2']:.1f} "
        f"(χ²₄₂: p = {after['mahalanobis2_p']:.2f})",
    ]
    if r["clamps"]["with_effect"]:
        lines.append(f"    {r['clamps']['with_effect']}")
    lines += ["", "  pose error (the pose from the readings against the tracker), mm and degrees:"]
    for a in r["pose_accuracy"]:
        where = "held-out" if a["heldout"] else "all poses"
        lines.append(
            f"    {a['model']:<26} position {a['position_rms_mm']:.4f} RMS, "
            f"{a['position_p95_mm']:.4f} p95; orientation {a['orientation_rms_deg']:.4f}° ({where})"
        )
    last = r["pose_accuracy"][-1]
    if last.get("floor_position_rms_mm") is not None:
        lines.append(
            f"    {'noise floor':<26} position {last['floor_position_rms_mm']:.4f} RMS; "
            f"orientation {last['floor_orientation_rms_deg']:.4f}°"
        )
    # What the diagnosis named (not the hidden truth), and a report named after this session:
    # a second session's advice must not write over the first's report.
    named = [] if d["named"] in ("none", "unexplained", "noise_understated") else [d["named"]]
    report = advice.beside(r["session"], "report", ".html")
    lines += [
        "",
        "  next: the diagnosis with its figures, as one HTML page:",
        advice.line(advice.command("diagnose", r["session"], *_add(named), "--report", report)),
    ]
    return "\n".join(lines)


def _add(effects: list[str]) -> list[str]:
    return ["--add", *effects] if effects else []
