"""The text UI's decide step (:mod:`hexcal.tui.decide`), driven by Textual's Pilot at 80×24: a
look-alike session (:mod:`hexcal.sim.plan_cases`) on the mock rig, through the real drivers,
from the diagnosis that offers a plan to the verdict that decides it."""

from __future__ import annotations

import asyncio

import numpy as np
import pytest
from test_tui import _settle, _until

from hexcal.app.cli import main
from hexcal.procedure.session import load_session
from hexcal.tui.app import HexcalApp
from hexcal.tui.decide import PLAN_STEP, DecideScreen
from hexcal.tui.record import RecordScreen
from hexcal.tui.results import DiagnosisScreen, ResultScreen

SMALL = (80, 24)


def _text(screen, *ids: str) -> str:
    return "\n".join(str(screen.query_one(i).render()) for i in ids)


@pytest.mark.slow
def test_a_look_alike_session_is_decided_by_its_planned_poses(tmp_path, quick_pilot, monkeypatch):
    """Thermal expansion hidden, the temperature rising over the session (the worked example's
    pair, docs/diagnosis.md): the diagnosis names drift and cannot resolve thermal, and offers a
    plan; p plans it, g drives the mock platform to the first pose and r records it, a the
    rest; after each the diagnosis runs again. It ends decided — thermal resolved and named, the
    effect the mock robot hides — within the planned poses, each recorded where it was planned,
    and the diagnosis screen shows the new verdict."""
    path = tmp_path / "session.json"
    made: list[HexcalApp] = []
    monkeypatch.setattr(HexcalApp, "run", lambda self, *a, **k: made.append(self))
    argv = ["run", "--mock", "--look-alike", "thermal-drift", "--seed", "2", "--session"]
    assert main([*argv, str(path), "--sessions", str(tmp_path)]) == 0
    (app,) = made  # as `hexcal run` made it, the look-alike session written to resume
    n_session = len(load_session(path).poses)

    async def run():
        async with app.run_test(size=SMALL) as pilot:
            await pilot.press("ctrl+r")
            await _until(pilot, lambda: isinstance(app.screen, RecordScreen), 30)
            assert app.guided.finished
            await pilot.press("k")
            await _until(pilot, lambda: isinstance(app.screen, ResultScreen), 5)
            await _settle(pilot)
            await pilot.press("d")
            await _until(pilot, lambda: isinstance(app.screen, DiagnosisScreen), 5)
            diag = app.screen
            await _until(pilot, lambda: len(diag.history) == 1 and not diag.busy, 60)
            first = diag.history[0]
            assert "press p to record them and decide" in _text(diag, "#diag-summary")
            await pilot.press("p")
            await _until(pilot, lambda: isinstance(app.screen, DecideScreen), 5)
            screen = app.screen
            await _until(pilot, lambda: screen.plan is not None, 60)
            planned = screen.plan.meas
            # The first pose by hand: go there, record; the diagnosis runs again.
            await pilot.press("g")
            await pilot.press("r")
            await _until(pilot, lambda: len(screen.rows) == 2 and not screen.busy, 60)
            assert screen.recorded == 1
            # The rest with the mock operator, until decided or the plan is spent.
            await pilot.press("a")
            await _until(pilot, lambda: screen.ended is not None and not screen.busy, 180)
            said = _text(screen, "#decide-table", "#decide-said", "#decide-next")
            await pilot.press("r")  # the step has ended: r says so
            refused = _text(screen, "#status")
            poses = [r for r in app.guided.sf.session.poses if r.step == PLAN_STEP]
            await pilot.press("escape")
            await _until(pilot, lambda: app.screen is diag, 5)
            await _until(pilot, lambda: len(diag.history) == 1 and not diag.busy, 60)
            return first, screen, planned, said, refused, poses, diag.history[0]

    first, screen, planned, said, refused, poses, after = asyncio.run(run())
    offer = first.plans[0]
    assert (str(first.verdict), offer.kind, offer.hypotheses) == ("drift", "resolve", ("thermal",))
    assert screen.rows[0][1].hypotheses == ("thermal", "drift")
    assert not screen.rows[0][1].decided
    # Decided, not spent: thermal, what the mock robot hides, within the plan's poses.
    assert screen.ended == "decided"
    last = screen.rows[-1][1]
    assert last.decided and last.winner == "thermal" == app.rig.hidden["name"]
    n = screen.recorded
    assert 1 <= n <= len(planned) == offer.n_planned
    assert [k for k, _, _ in screen.rows] == list(range(n + 1))  # one diagnosis per pose
    assert f"Decided after {n} planned pose" in said and f"of {len(planned)}" in said
    assert "decided: thermal is resolved and named" in said
    assert "has ended (decided)" in refused
    # Every planned pose recorded once, through the drivers, where it was planned: the tracker
    # reads the pose the platform was driven to (its noise 0.01 mm, so 0.1 mm is 10σ).
    assert len(poses) == n
    got = np.array([r.position for r in poses])
    assert np.abs(got - planned.position[:n]).max() < 0.1
    saved = load_session(tmp_path / "session.json")
    assert len(saved.poses) == n_session + n
    assert [r.step for r in saved.poses[-n:]] == [PLAN_STEP] * n
    # Back on the diagnosis screen: diagnosed again on every pose, thermal named.
    assert str(after.verdict) == "thermal"


def test_a_look_alike_session_is_for_the_mock_rig(tmp_path):
    with pytest.raises(SystemExit, match="--look-alike goes with --mock"):
        main(["run", "--look-alike", "thermal-drift", "--session", str(tmp_path / "s.json")])
    assert not (tmp_path / "s.json").exists()


@pytest.mark.slow
def test_a_plan_spent_undecided_says_so_and_keeps_the_latest_rows_in_view(
    tmp_path, quick_pilot, monkeypatch
):
    """The screen's other ending (the rules that decide are tests/test_decide.py's; here they
    are held undecided): eight planned poses, every one recorded by the mock operator and
    diagnosed, then 'Plan spent'; at 80×24 the table keeps the session's row and the latest
    four, the gap marked."""
    from dataclasses import replace

    import hexcal.diagnosis.decide as decide
    from hexcal.diagnosis.plan_offer import Offer

    real = decide.standing
    monkeypatch.setattr(
        decide,
        "standing",
        lambda *a, **k: replace(real(*a, **k), decided=False, winner=None, words="held open"),
    )
    path = tmp_path / "session.json"
    made: list[HexcalApp] = []
    monkeypatch.setattr(HexcalApp, "run", lambda self, *a, **k: made.append(self))
    argv = ["run", "--mock", "--look-alike", "thermal-drift", "--seed", "2", "--session"]
    assert main([*argv, str(path), "--sessions", str(tmp_path)]) == 0
    (app,) = made

    async def run():
        async with app.run_test(size=SMALL) as pilot:
            await pilot.press("ctrl+r")
            await _until(pilot, lambda: isinstance(app.screen, RecordScreen), 30)
            await pilot.press("k")
            await _until(pilot, lambda: isinstance(app.screen, ResultScreen), 5)
            await _settle(pilot)
            await pilot.press("d")
            await _until(pilot, lambda: isinstance(app.screen, DiagnosisScreen), 5)
            diag = app.screen
            await _until(pilot, lambda: len(diag.history) == 1 and not diag.busy, 60)
            d = diag.history[0]
            app.push_screen(DecideScreen(Offer("resolve", ("thermal",), 8), d, ()))
            await _until(pilot, lambda: isinstance(app.screen, DecideScreen), 5)
            screen = app.screen
            await _until(pilot, lambda: screen.plan is not None, 60)
            await pilot.press("a")
            await _until(pilot, lambda: screen.ended is not None and not screen.busy, 240)
            return screen, _text(screen, "#decide-next", "#decide-table", "#decide-said")

    screen, said = asyncio.run(run())
    assert screen.ended == "spent" and screen.recorded == 8 == len(screen.plan.meas)
    assert [k for k, _, _ in screen.rows] == list(range(9))
    assert "Plan spent: all 8 planned poses recorded" in said
    assert "undecided: held open" in said
    table = said.split("\n")
    shown = [line.split()[0] for line in table if line.strip()[:1].isdigit() or "⋮" in line]
    assert shown == ["0", "⋮", "5", "6", "7", "8"]
    plan_poses = [r for r in app.guided.sf.session.poses if r.step == PLAN_STEP]
    assert len(plan_poses) == 8
