"""``hexcal diagnose``: compare the model with the measurements and find the missing effect."""

from __future__ import annotations

import argparse
import itertools
import math
import shlex
from pathlib import Path
from typing import TYPE_CHECKING

from hexcal.app.commands.common import (
    add_effects_option,
    add_model_option,
    add_pose_selection,
    check_outputs,
    load_effects,
    read_inputs,
    report_mismatch,
)
from hexcal.app.progress import Progress, progress, wanted
from hexcal.errors import InputError

if TYPE_CHECKING:
    from hexcal.app.workflow import Inputs, ModelResult
    from hexcal.diagnosis.diagnose import Diagnosis


#: The command's name on the command line.
NAME = "diagnose"


def add_parser(sub: argparse._SubParsersAction) -> None:
    """The ``diagnose`` command and its options."""
    d = sub.add_parser(
        NAME, help="compare the model with the measurements and find the missing effect"
    )
    d.add_argument(
        "measurements", type=Path, help="measurements.csv (docs/formats.md) or a session file"
    )
    d.add_argument("--robot", type=Path, help="robot.json (a session file carries its own)")
    add_model_option(d)
    d.add_argument(
        "--instruments", type=Path, help="instruments.json: the noise that sets the floor"
    )
    d.add_argument(
        "--add",
        nargs="+",
        metavar="EFFECT",
        help="effects already in the model (the catalogue's, or loaded with --effects)",
    )
    add_effects_option(d)
    d.add_argument(
        "--auto",
        action="store_true",
        help="add the named effect and go on until the verdict is none",
    )
    d.add_argument("--json", action="store_true", help="print one JSON object")
    d.add_argument(
        "--verbose", action="store_true", help="every step of the chain in full (with --auto)"
    )
    d.add_argument("--plots", help="directory for the residual plots (PNG)")
    d.add_argument("--report", help="write one self-contained HTML report here")
    d.add_argument(
        "--residuals", help="write predicted against measured for every pose and leg (CSV)"
    )
    d.add_argument(
        "--out",
        type=Path,
        help="write the last step's calibrated model here (calibrated.json, with its effects)",
    )
    d.add_argument("--force", action="store_true", help="replace an existing --out file")
    d.add_argument(
        "--effect-file",
        type=Path,
        metavar="FILE.py",
        help="when the residual is unexplained, write a ready-to-edit effect whose basis is the "
        "covariate it follows (pass it back with --effects)",
    )
    d.add_argument(
        "--explore",
        type=Path,
        metavar="DIR",
        help="with --auto: when the residual is unexplained, write the explorer's lead as an "
        "effect file in DIR, add it and go on (two unknown effects: two files)",
    )
    d.add_argument(
        "--exclude-at-limits",
        action="store_true",
        help="leave out the poses with a leg at the end of its stroke or a joint at its limit",
    )
    add_pose_selection(d)
    d.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from hexcal.app.workflow import refuse_overwrite
    from hexcal.diagnosis.text import before_after_text, diagnosis_text
    from hexcal.io import json_out

    check_outputs(
        (args.out, "calibrated.json"),
        (args.residuals, "residuals.csv"),
        (args.report, "report.html"),
        (args.plots, "/"),
    )
    if args.explore is not None and not args.auto:
        raise InputError("--explore goes with --auto (it carries the chain through the leads)")
    load_effects(args)
    inp = read_inputs(args)
    for out_path in (args.out, args.residuals, args.report, args.effect_file):
        if out_path:
            refuse_overwrite(Path(out_path), inp, force=True)
    if args.out:
        refuse_overwrite(args.out, inp, args.force)
    from hexcal.diagnosis.limits import advice as limits_advice
    from hexcal.diagnosis.limits import at_limits

    sigma = None if inp.instruments is None else inp.instruments.sigma_reading_mm
    limits = at_limits(inp.meas, inp.design, sigma)
    limit_lines = limits.lines(inp.meas)
    limits_json = limits.to_dict(inp.meas)
    if args.exclude_at_limits and limits.rows:
        inp = inp.without([int(inp.meas.pose_id[r]) for r in limits.rows])
    with progress(wanted(args.json)) as bar:
        steps, result, mismatch = _diagnose_and_write(inp, args, bar, limit_lines)
    effect_written = (
        _write_effect_file(steps[-1], args.effect_file, inp) if args.effect_file else None
    )
    from hexcal.app.workflow import reboot_findings
    from hexcal.diagnosis.metrology import of_diagnosis

    reboots = reboot_findings(inp, steps)
    figures = of_diagnosis(steps[-1])
    if args.json:
        out = _json_of(steps, args, limits_json, figures, result, effect_written)
        out["encoder_reboots"] = [r.to_dict() for r in reboots]
        print(json_out.dumps(out, why=json_out.accuracy_reason, indent=2))
    else:
        from hexcal.app.plain import diagnosis_summary, opening

        for r in reboots:  # a known pose, tested first: before what the search and fit say
            print(f"{r.text()}\n")
        print(opening(diagnosis_summary(steps, args)))
        if limit_lines:
            left = "; left out (--exclude-at-limits)" if args.exclude_at_limits else ""
            print(f"poses at the end of a leg's stroke or a joint's limit{left}:")
            print("\n".join(f"  {line}" for line in limit_lines))
            if not args.exclude_at_limits:
                print(f"  {limits_advice(inp.design)}")
            print()
        shown = steps if args.verbose else steps[-1:]
        if len(shown) < len(steps):
            print(
                f"(the chain's {len(steps) - 1} earlier step(s) in full: --verbose; the error "
                "falling, step by step, is below)\n"
            )
        for d in shown:
            print(diagnosis_text(d, inp.label, plan_command=plan_command(args)))
            print()
        print(before_after_text(steps))
        print()
        print("\n".join(figures.lines()))
        if args.plots:
            print(f"plots written to {args.plots}/")
        if args.report:
            print(f"report written to {args.report}")
        if result is not None and not mismatch:
            print(f"calibrated model ({result.name}) written to {args.out}")
        if args.effect_file:
            print(_effect_file_line(effect_written, args))
        for f in _explored_files(steps, args.explore) if args.explore is not None else []:
            print(
                f"effect {f['effect']} (the explorer's lead along the {f['covariate']}) written to "
                f"{f['path']} and added; edit it, then --effects {f['path']} --add {f['effect']}"
            )
    return report_mismatch(mismatch, args)


def _step_rows(steps: list[Diagnosis]) -> list[dict]:
    """The chain's steps, one object each, for ``--json``."""
    return [
        {
            "model": d.fit.model_name,
            "effects": list(d.effects),
            "cv_rms_mm": d.fit.cv_rms_mm,
            "cv_blocked_rms_mm": d.fit.cv_blocked_rms_mm,
            # the step before on this step's poses, where the two set aside other outliers
            "cv_rms_before_same_poses_mm": (
                float(d.cv_rms_before_mm) if math.isfinite(d.cv_rms_before_mm) else None
            ),
            "poses_used": len(d.problem.meas),
            "noise_floor_mm": d.noise_floor_mm,
            "verdict": d.verdict,
            "pose_accuracy": None if d.accuracy is None else d.accuracy.to_dict(),
        }
        for d in steps
    ]


def _json_of(
    steps: list[Diagnosis],
    args: argparse.Namespace,
    limits_json: dict,
    figures,
    result: ModelResult | None,
    effect_written: dict | None,
) -> dict:
    """The ``--json`` object: the last step's diagnosis, the chain's steps, the poses at the
    limits, the metrology figures and the files written."""
    out = steps[-1].to_dict()
    if len(steps) > 1:
        out["steps"] = _step_rows(steps)
    out["at_limits"] = limits_json
    out["at_limits"]["excluded"] = bool(args.exclude_at_limits)
    out["metrology"] = figures.to_dict(per_pose=False)
    if result is not None:
        out["written"] = {"path": str(args.out), "model": result.name}
    if args.effect_file:
        out["effect_file"] = effect_written
    if args.explore is not None:
        out["explored_files"] = _explored_files(steps, args.explore)
    for offer, row in zip(steps[-1].plans, out["plans"], strict=True):
        row["command"] = f"{plan_command(args)} {shlex.join(offer.args())}"
    return out


def plan_command(args: argparse.Namespace) -> str:
    """``hexcal plan`` with the user's own session, robot, noise and model arguments."""
    words = ["hexcal", "plan", str(args.measurements)]
    if args.robot:
        words += ["--robot", str(args.robot)]
    if args.instruments:
        words += ["--instruments", str(args.instruments)]
    if args.model != 42:
        words += ["--model", str(args.model)]
    if args.add:
        words += ["--add", *args.add]
    if args.effects:
        words += ["--effects", *map(str, args.effects)]
    return shlex.join(words)


def _explored_files(steps: list[Diagnosis], directory: Path) -> list[dict]:
    """The effect files the chain wrote in ``directory`` and added, in the chain's order."""
    out = []
    for before, d in itertools.pairwise(steps):
        new = [e for e in d.effects if e not in before.effects]
        lead = before.exploration.lead if before.exploration is not None else None
        for e in new:
            path = directory / f"{e}.py"
            if lead is not None and path.exists():
                out.append({"path": str(path), "effect": e, "covariate": lead.covariate.name})
    return out


def _write_effect_file(d: Diagnosis, path: Path, inp: Inputs) -> dict:
    """The effect file of the chain's last step, when its residual points somewhere:
    ``{"path", "effect", "covariate"}``, or ``{"path": None, "reason"}``."""
    from hexcal.diagnosis.effect_file import effect_name, write_effect_file

    lead = None if d.exploration is None else d.exploration.lead
    if lead is None:
        why = (
            f"the verdict is {d.verdict}"
            if d.exploration is None
            else "the residual follows none of the covariates"
        )
        return {"path": None, "reason": f"no effect file written: {why}"}
    write_effect_file(lead, path, inp.label)
    return {"path": str(path), "effect": effect_name(lead), "covariate": lead.covariate.name}


def _effect_file_line(written: dict | None, args: argparse.Namespace) -> str:
    from hexcal.io.advice import diagnose_command, line

    if not written or written.get("path") is None:
        return (written or {}).get("reason", "no effect file written")
    again = diagnose_command(args, add=[written["effect"]], effects=[written["path"]])
    return (
        f"effect {written['effect']} (along the {written['covariate']}) written to "
        f"{written['path']}: edit it, then run\n{line(again)}"
    )


def _diagnose_and_write(
    inp: Inputs, args: argparse.Namespace, bar: Progress, limit_lines: list[str]
) -> tuple[list[Diagnosis], ModelResult | None, list[str]]:
    """The diagnosis chain, the calibrated model, the drawing check and the files asked for,
    each stage shown on ``bar``: (steps, the model to write or None, drawing mismatches)."""
    from hexcal.app.workflow import diagnose_chain, model_of, save_result
    from hexcal.vocabulary import ModelKind, names_an_addition

    def next_step(d: Diagnosis) -> None:
        if args.auto and names_an_addition(d.verdict):
            bar.stage(f"diagnosing {d.fit.model_name} + {d.verdict}")

    model = ModelKind(args.model)
    added = "".join(f" + {e}" for e in args.add or ())
    bar.stage(f"diagnosing Model {int(model)}{added}")
    explore = getattr(args, "explore", None)
    if explore is not None:
        explore.mkdir(parents=True, exist_ok=True)
    steps = diagnose_chain(
        inp,
        model,
        add=tuple(args.add or ()),
        auto=args.auto,
        on_step=next_step,
        explore_dir=explore,
    )
    result = model_of(inp, steps, model) if args.out else None
    mismatch = []
    if not args.no_drawing_check:
        from hexcal.estimate.sanity import check_against_drawing

        ref = steps[0].fit.refinement
        found = check_against_drawing(ref.a, ref.b, inp.design, args.drawing_tolerance)
        mismatch = [f.text for f in found]
    if result is not None and not mismatch:
        save_result(result, args.out, inp, args.force)
    if args.plots:
        from hexcal.diagnosis.compare_plots import before_after_job, pose_error_job
        from hexcal.diagnosis.figure_pool import draw_all
        from hexcal.diagnosis.plots import plot_jobs
        from hexcal.io.fileio import new_folder

        with new_folder(args.plots) as out:  # removed again if it was made and stays empty
            jobs = plot_jobs(steps[-1], out)
            jobs.append(pose_error_job(steps, out / "pose_error.png"))
            jobs += [
                before_after_job(steps[i - 1], steps[i], out / f"before_after_{i}.png")
                for i in range(1, len(steps))
            ]
            bar.stage("drawing the plots", total=len(jobs))

            def advance(_path: Path) -> None:
                bar.advance()

            draw_all(jobs, advance)
    if args.residuals:
        from hexcal.io.fileio import write_text_atomic

        write_text_atomic(args.residuals, steps[-1].residual_table())
    if args.report:
        from hexcal.diagnosis.limits import advice
        from hexcal.diagnosis.report import figure_count, write_report

        bar.stage("writing the report", total=figure_count(steps))
        write_report(
            steps,
            Path(args.report),
            dict(inp.files),
            limits=limit_lines,
            on_figure=bar.advance,
            limits_advice=advice(inp.design),
        )
    return steps, result, mismatch
