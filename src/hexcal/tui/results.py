"""The result screens: the Model 36/42 calibration, then the diagnosis.

The diagnosis compares the model with the measurements (held-out residuals per leg against the
noise floor, in a terminal plot), says where it fails, ranks the missing effects, and adds the
one it names (``a``): the refit is shown beside the previous ones, so the operator watches the
error fall until the verdict is ``none``. Every calibration and diagnosis is stored in the
session file; ``e`` exports the session as plain files. Computations run in worker threads.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from rich.markup import escape
from textual import work
from textual.binding import Binding
from textual.containers import Horizontal, VerticalScroll
from textual.widgets import Header, Static
from textual_plotext import PlotextPlot

from hexcal.procedure.guided import GuidedSession
from hexcal.procedure.steps import Procedure
from hexcal.tui.backend import Rig
from hexcal.tui.fit import reflow
from hexcal.tui.screen import Foot, HexcalScreen
from hexcal.tui.working import Working
from hexcal.vocabulary import Outcome


def _app_state(screen: HexcalScreen) -> tuple[GuidedSession, Procedure, Rig | None]:
    app = screen.hexcal
    if app.guided is None or app.procedure is None:
        raise RuntimeError("the results need a guided session and its procedure: none is open")
    return app.guided, app.procedure, app.rig


def session_inputs(guided) -> Any:
    """The workflow's inputs of the guided session (its noise from the still windows)."""
    from hexcal.app.workflow import session_inputs as inputs

    return inputs(guided.sf.session, guided.sf.path)


class ResultScreen(HexcalScreen):
    """The calibrated geometry with its intervals (see :func:`hexcal.app.report_text`)."""

    BINDINGS = [
        Binding("d", "diagnose", "diagnose"),
        Binding("e", "export", "export"),
        Binding("escape", "back", "back to recording"),
        Binding("q", "app.quit", "quit"),
    ]

    def __init__(self) -> None:
        super().__init__()
        self.refused: str | None = None  # why the poses do not calibrate yet
        self._text = "calibrating…"

    def compose(self):
        yield Header()
        yield Foot()
        yield Working(id="working")
        with VerticalScroll(id="result-scroll"):
            yield Static("calibrating…", id="result")

    def on_mount(self) -> None:
        self.query_one("#result-scroll").focus()  # the arrows scroll the tables
        _, proc, _ = _app_state(self)
        self._working = self.query_one(Working)
        self._working.start(f"calibrating Model {int(proc.model)}")
        self._calibrate()

    def why_not(self, action: str) -> str | None:
        if action == "diagnose" and self.refused is not None:
            return "the poses do not calibrate yet: Escape, record more"
        return None

    @work(thread=True, exclusive=True, group="compute")
    def _calibrate(self) -> None:
        from hexcal.app.plain import STATISTICS, calibration_summary
        from hexcal.app.report_text import calibration_text
        from hexcal.app.workflow import calibrate_model, check_drawing, store
        from hexcal.estimate.accuracy import accuracy_table

        guided, proc, rig = _app_state(self)
        try:
            inp = session_inputs(guided)
            result = calibrate_model(
                inp, proc.model, on_stage=lambda text: self.hexcal.post(self._working.stage, text)
            )
        except (ValueError, np.linalg.LinAlgError) as exc:  # refusals name the motion to add
            self.hexcal.post(self._refused, str(exc))
            return
        cal = result.calibration
        mismatch = check_drawing(inp, cal)
        # Plain words first, as the command line and the report open.
        plain = calibration_summary(result.name, result.accuracy, mismatch, "press d to diagnose")
        text = "[b]" + escape(plain[0]) + "[/b]\n" + escape("\n".join(plain[1:]))
        text += (
            "\n\n[b]"
            + STATISTICS
            + "[/b]\n"
            + escape(calibration_text(cal, inp.label, inp.noise_source, verbose=False))
        )
        if mismatch:
            # Not a success, however well it fits: say so first.
            text = (
                "[red b]the calibration does not match the drawing:[/red b]\n"
                + escape("\n".join(mismatch))
                + "\n[red]fix the cause (cables, node ids, columns) before using it[/red]\n\n"
                + text
            )
        text += (
            "\n\n[b]pose accuracy[/b] (the pose computed from the readings, against the tracker):\n"
        )
        text += escape(accuracy_table(result.accuracy))
        if rig is not None and rig.truth is not None and cal.refinement is not None:
            text += "\n\n" + truth_line(cal.refinement, rig.truth)
        text += "\n\n" + escape("\n".join(metrology_lines(result, inp)))
        store(guided.sf, "calibration", result, inp.meas)
        self.hexcal.post(self._show, text + "\n\n[b]d[/b] diagnose   [b]e[/b] export")

    def _show(self, text: str) -> None:
        self._working.stop()
        self._text = text
        self._fit()

    def on_resize(self) -> None:
        self.call_after_refresh(self._fit)

    def _fit(self) -> None:
        scroll = self.query_one("#result-scroll", VerticalScroll)
        width = scroll.size.width - 4
        self.query_one("#result", Static).update(reflow(self._text, width))
        if max(len(line) for line in reflow(self._text, width).split("\n")) > width:
            self.status("a table is wider than the window: ← → scroll it")

    def _refused(self, why: str) -> None:
        self.refused = why
        self._show(f"[red]cannot calibrate yet:[/red]\n{escape(why)}\n\nEscape to record more.")
        self.refresh_bindings()

    def action_diagnose(self) -> None:
        self.app.push_screen(DiagnosisScreen())

    def action_back(self) -> None:
        self.app.pop_screen()

    def action_export(self) -> None:
        self.status(*export_text(self))


def metrology_lines(result: Any, inp: Any) -> list[str]:
    """The calibrated model's metrology figures on the session's own poses (the uncertainty of
    its poses, ISO 9283 and ISO 230-2 when the session has their steps)."""
    from hexcal.app.workflow import floor_sigmas
    from hexcal.diagnosis.metrology import of_model_file

    r = result.calibration.refinement
    sig = floor_sigmas(inp, 1.0 if r is None else r.chi2 / r.dof)
    label = f"{result.name} on the poses it was fitted on"
    return of_model_file(result.file, inp.meas, sig, label).lines()


def truth_line(refinement: Any, truth: Any) -> str:
    """How a refined geometry compares with a simulated robot's truth, one line."""
    from hexcal.app.demo import against_truth

    t = against_truth(refinement, truth)
    return (
        f"[b]vs the simulator's truth[/b]: max error {t['max_error_mm']:.4f} mm, "
        f"{t['outside_95']}/{t['parameters']} outside 95 %, "
        f"Mahalanobis² {t['mahalanobis2']:.1f} (p {t['mahalanobis2_p']:.2f})"
    )


def export_text(screen: HexcalScreen) -> tuple[str, str]:
    """Export the session next to its file, the latest model as calibrated.json; one line for
    the operator, and its style."""
    from hexcal.app.workflow import export

    guided, _, _ = _app_state(screen)
    out = Path(guided.sf.path).with_suffix("")
    out = out.with_name(out.name + "-export")
    try:
        written = export(guided.sf.session, out)
    except (OSError, ValueError) as exc:
        return f"export failed: {exc}", "red"
    return f"exported to {out}/: {', '.join(written)}", "green"


#: The fewest rows of the diagnosis chart: title, frame, three rows of bars, axis, leg labels.
PLOT_MIN_ROWS = 7


class DiagnosisScreen(HexcalScreen):
    """Model against measurements, where it fails, the missing effect; add it, watch the error
    fall (see module docstring)."""

    BINDINGS = [
        Binding("a", "add", "add the named effect"),
        Binding("p", "decide", "plan, decide"),
        Binding("e", "export", "export"),
        Binding("escape", "back", "back"),
        Binding("q", "app.quit", "quit"),
    ]

    def __init__(self) -> None:
        super().__init__()
        self.history: list[Any] = []
        self.busy = False
        self._plot_rows: int | None = None  # the chart's height set by _size_plot
        self._poses = 0  # the session's poses when last diagnosed

    def compose(self):
        yield Header()
        yield Foot()
        yield Working(id="working")
        # One scroll: the summary beside the chart (above it when narrow), then the details.
        with VerticalScroll(id="diag-scroll"):
            with Horizontal(id="diag-top"):
                yield Static(
                    "diagnosing… (every catalogue effect is scored and the leaders refitted)",
                    id="diag-summary",
                )
                yield PlotextPlot(id="diag-plot")
            yield Static("", id="diag-text")

    def on_mount(self) -> None:
        self.busy = True
        self._details = ""
        self.query_one("#diag-scroll").focus()  # the arrows scroll
        _, proc, _ = _app_state(self)
        self._working = self.query_one(Working)
        self._working.start(f"diagnosing Model {int(proc.model)}")
        self._diagnose(())

    def on_resize(self) -> None:
        self.call_after_refresh(self._fit)

    def _fit(self) -> None:
        width = self.query_one("#diag-scroll").size.width - 4
        self.query_one("#diag-text", Static).update(escape(reflow(self._details, width)))
        if self.history:
            self._plot()
        self.call_after_refresh(self._size_plot)

    def _size_plot(self) -> None:
        """On a short, narrow screen (80×24) the chart takes the rows the summary leaves, at
        least :data:`PLOT_MIN_ROWS`, so that both are seen whole, leg labels included, however
        many models the summary lists; elsewhere the stylesheet's height."""
        plot = self.query_one("#diag-plot", PlotextPlot)
        height = None
        if self.has_class("-narrow") and self.has_class("-short"):
            view = self.query_one("#diag-scroll", VerticalScroll).scrollable_content_region
            summary = self.query_one("#diag-summary", Static).outer_size.height
            height = max(PLOT_MIN_ROWS, view.height - summary)
        if height != self._plot_rows:
            self._plot_rows = height
            plot.styles.height = height
            if self.history:
                self.call_after_refresh(self._plot)  # its y range depends on its rows

    def why_not(self, action: str) -> str | None:
        if action not in ("add", "decide"):
            return None
        if self.busy or not self.history:
            return "diagnosing: wait for the verdict"
        d = self.history[-1]
        if action == "decide":
            return None if d.plans else "the poses decide already: the diagnosis offers no plan"
        if d.verdict == Outcome.NONE:
            return "the residual is at the noise floor: there is no effect to add"
        if d.verdict == Outcome.UNEXPLAINED and _lead(d) is None:
            return "no catalogue effect explains the residual, and it follows no covariate"
        if d.verdict == Outcome.NOISE_UNDERSTATED:
            return "the stated noise looks too low: there is no effect to add"
        return None

    @work(thread=True, exclusive=True, group="compute")
    def _diagnose(self, add: tuple[str, ...], explored: bool = False) -> None:
        from hexcal.app.workflow import diagnose_chain, model_of, store
        from hexcal.diagnosis.effect_file import write_explored

        guided, proc, _ = _app_state(self)
        try:
            inp = session_inputs(guided)
            prev = self.history[-1] if self.history else None
            if explored and prev is not None:
                # The explorer's lead, written beside the session file as an effect file (the
                # lab edits it to the physics it suspects) and added.
                where = guided.sf.path.parent / f"{guided.sf.path.stem}-effects"
                where.mkdir(exist_ok=True)
                name = write_explored(prev, where, inp.label)
                if name is None:
                    raise ValueError("the residual follows no covariate: nothing to add")
                add = (*add, name)
                self.hexcal.post(self.status, f"the lead written to {where / name}.py and added")
            (d,) = diagnose_chain(inp, proc.model, add=add, previous=prev)
            self.hexcal.post(self._working.stage, f"{d.fit.model_name}: the calibrated model")
            # The step's model as a lab ships it: calibrated with its effects, clamps included.
            result = model_of(inp, [*self.history, d], proc.model)
        except (ValueError, np.linalg.LinAlgError) as exc:
            self.hexcal.post(self._failed, str(exc))
            return
        store(guided.sf, "diagnosis", result, inp.meas, summary=d.to_dict())
        self.hexcal.post(self._show, d)

    def _failed(self, msg: str) -> None:
        self._working.stop()
        self.busy = False
        self.query_one("#diag-text", Static).update(f"[red]cannot diagnose: {msg}[/red]")
        self.refresh_bindings()

    def _show(self, d: Any) -> None:
        from hexcal.app.plain import pose_against_floor, verdict_words
        from hexcal.diagnosis.text import before_after_text, diagnosis_text

        self._working.stop()
        self.history.append(d)
        self.busy = False
        guided, _, rig = _app_state(self)
        self._poses = len(guided.sf.session.poses)
        self._details = (
            before_after_text(self.history)
            + "\n\n"
            + diagnosis_text(d, str(guided.sf.path), add="key a")
        )
        self._fit()
        # Plain words first: the verdict, then the pose error against what the instruments
        # allow; the statistics follow in the details below the chart.
        lines = [
            f"[b]{escape(verdict_words(d))}[/b]",
            f"{escape(pose_against_floor(d.accuracy))}   (verdict: {d.verdict})",
            "",
            f"{'model':<22}{'legs µm':>9}{'pose µm':>9}{'angle °':>9}",
            *(_history_line(h) for h in self.history),
            "",
        ]
        if d.verdict == Outcome.NONE:
            lines.append("[green]the residual is at the noise floor: nothing is missing[/green]")
        elif d.verdict == Outcome.UNEXPLAINED:
            lines.append(
                "[yellow]a structured residual no catalogue effect explains[/yellow]: "
                + escape(d.where["summary"])
            )
            lead = _lead(d)
            if lead is not None:
                shape = escape(lead.shape.describe(lead.covariate.unit))
                lines.append(
                    f"it follows the [b]{escape(lead.covariate.label)}[/b] "
                    f"({100 * lead.share:.0f} % of the excess): {escape(lead.points_at)}; "
                    f"press [b]a[/b] to add it as an effect ({shape}) and refit"
                )
                lines += [escape(line) for line in lead_sketch(d, lead)]
        elif d.verdict == Outcome.NOISE_UNDERSTATED:
            lines.append(
                f"[yellow]the stated noise looks about {d.noise_factor:.1f}× too low[/yellow]: the "
                "residual is spread evenly everywhere"
            )
        else:
            lines.append(f"press [b]a[/b] to add [b]{d.verdict}[/b] and refit")
        if d.plans:
            lines.append(
                f"[yellow]{escape(d.plans[0].text())}[/yellow]: press [b]p[/b] to record them "
                "and decide"
            )
        if rig is not None and rig.hidden is not None:
            lines.append(f"(the mock robot hides: {rig.hidden['name']})")
            if d.fit.refinement is not None:
                lines.append(truth_line(d.fit.refinement, rig.truth))
        self.query_one("#diag-summary", Static).update("\n".join(lines))
        # The new verdict is what the user came for: back to the top, where it is.
        self.query_one("#diag-scroll", VerticalScroll).scroll_home(animate=False)
        self.status("")
        self._plot()
        self.refresh_bindings()

    def _plot(self) -> None:
        """Held-out RMS per leg of each model of the chain, the noise floor as a red line. The
        legend sits in the top rows, which the y range leaves free of bars; where the chart
        has too few rows for a legend of every model (80×24), it shows the fall: the first
        model and the last, side by side in each leg's pair of bars, named in its title."""
        plot = self.query_one("#diag-plot", PlotextPlot)
        plt = plot.plt
        plt.clear_figure()
        bar_rows = max(1, plot.size.height - 4)  # less the title, frame, axis and leg labels
        shown = self.history
        if len(shown) > 2 and bar_rows - (len(shown) + 1) < 2:
            shown = [shown[0], shown[-1]]  # before and after: the fall
        legend = bar_rows - (len(shown) + 1) >= 2
        rms = [(1000 * d.fit.cv_rms_per_leg).tolist() for d in shown]
        plt.multiple_bar(
            [f"leg {k}" for k in range(1, 7)],
            rms,
            # plotext takes ``labels`` (one per series); textual-plotext's stub says ``label``.
            labels=[d.fit.model_name for d in shown] if legend else None,  # type: ignore[call-arg]
        )
        floor = 1000 * self.history[-1].noise_floor_mm
        plt.hline(floor, "red")
        top = max(floor, *(max(r) for r in rms))
        free = len(shown) + 1 if legend else 0
        plt.ylim(0, top * bar_rows / max(1, bar_rows - free))
        kind = "estimated noise floor" if self.history[-1].floor_estimated else "noise floor"
        short = "estimated floor" if self.history[-1].floor_estimated else "floor"
        if legend:
            plt.title(f"held-out RMS per leg, µm — red: {kind} {floor:.1f} µm")
        elif len(shown) == 1:
            plt.title(f"held-out RMS per leg of {shown[0].fit.model_name}, µm — red: {short}")
        else:
            first, last = shown[0].fit.model_name, shown[-1].fit.model_name
            plt.title(f"µm per leg: {first} (left) → {last} (right); red: {short}")
        plot.refresh()

    def action_add(self) -> None:
        d = self.history[-1]
        self.busy = True
        self.refresh_bindings()
        held = tuple(e for e in d.effects if e != "offset")
        lead = _lead(d) if d.verdict == Outcome.UNEXPLAINED else None
        if lead is not None:
            self._working.start(f"adding the lead along the {lead.covariate.name} and refitting")
            self._diagnose(held, explored=True)
            return
        self._working.start(f"adding {d.verdict} and refitting")
        self._diagnose((*held, d.verdict))

    def action_export(self) -> None:
        self.status(*export_text(self))

    def action_decide(self) -> None:
        """The decide step for the first plan offered (:mod:`hexcal.tui.decide`)."""
        from hexcal.tui.decide import DecideScreen

        d = self.history[-1]
        held = tuple(e for e in d.effects if e != "offset")
        self.app.push_screen(DecideScreen(d.plans[0], d, held))

    def hidden(self, action: str) -> bool:
        return action == "decide" and not (self.history and self.history[-1].plans)

    def on_screen_resume(self) -> None:
        """Back from the decide step with more poses: the chain is diagnosed again on them."""
        guided, _, _ = _app_state(self)
        n = len(guided.sf.session.poses)
        if self.busy or not self.history or n == self._poses:
            return
        held = tuple(e for e in self.history[-1].effects if e != "offset")
        self.history = []
        self.busy = True
        self.refresh_bindings()
        self._working.start(f"diagnosing again on {n} poses")
        self._diagnose(held)

    def action_back(self) -> None:
        self.app.pop_screen()


#: Bars of a sketch, lowest first.
_BARS = "▁▂▃▄▅▆▇█"


def lead_sketch(d: Any, lead: Any, width: int = 32) -> list[str]:
    """The residual against the lead's covariate, and the lead's fitted shape, as two rows of
    bars on the leg that carries most of it: each bar one of ``width`` bins of the covariate
    (its median held-out residual; the shape's mean), both on one scale."""
    legs = list(lead.shape.legs)
    seen = lead.seen_um()  # µm, as the residual sees it
    if seen is None or not legs:
        return []
    k = max(legs, key=lambda leg: float(np.ptp(seen[:, leg - 1]))) - 1
    axis, _, axis_name = lead.axis()
    u = np.asarray(axis)[:, k]
    resid = np.asarray(d.fit.held_out_residuals)[:, k] * 1000.0
    curve = seen[:, k]
    edges = np.linspace(u.min(), u.max(), width + 1)
    where = np.clip(np.searchsorted(edges, u, side="right") - 1, 0, width - 1)
    cells = [(resid[where == i], curve[where == i]) for i in range(width)]
    got = [(float(np.median(r)), float(np.mean(c))) for r, c in cells if len(r)]
    if len(got) < 2:
        return []
    lo = min(min(a, b) for a, b in got)
    hi = max(max(a, b) for a, b in got)
    span = max(hi - lo, 1e-9)

    def bars(values: list[float]) -> str:
        return "".join(_BARS[round((v - lo) / span * (len(_BARS) - 1))] for v in values)

    cov = lead.covariate
    unit = " µm" if axis_name != cov.name else f" {cov.unit}" if cov.unit else ""
    return [
        f"leg {k + 1}, {axis_name} {u.min():.4g} … {u.max():.4g}{unit}; {lo:.0f} … {hi:.0f} µm:",
        f"  residual   {bars([a for a, _ in got])}",
        f"  its shape  {bars([b for _, b in got])}",
    ]


def _lead(d: Any) -> Any:
    """The explorer's proposed lead of diagnosis ``d``, or None."""
    return None if d.exploration is None else d.exploration.lead


def _history_line(d: Any) -> str:
    """One model of the chain: held-out leg RMS and pose error (µm, degrees)."""
    acc = d.accuracy
    pose = (
        f"{1000 * acc.position_rms_mm:9.2f}{acc.orientation_rms_deg:9.4f}"
        if acc is not None
        else ""
    )
    return f"{d.fit.model_name:<22}{1000 * d.fit.cv_rms_mm:9.2f}{pose}"
