"""A rebooted encoder is checked (hexcal.procedure.reboots, hexcal.diagnosis.reboot), on the mock
rig through the real CAN driver: leg 3's node reboots mid-session and comes back 7 mm off (a
lost preset). The poses after it are marked in the session, set-up flags the jump against the
tracker's pose and the model at once, and the diagnosis names the zero step at that pose."""

from __future__ import annotations

import json
import time

import numpy as np
import pytest

from hexcal.acquire.acquisition import StillWindow
from hexcal.acquire.live import open_rig
from hexcal.app.cli import main
from hexcal.app.demo import hidden_robot
from hexcal.mock_hw.rig import mock_rig
from hexcal.procedure.recording import record_procedure
from hexcal.procedure.session import Session, SessionFile, load_session
from hexcal.procedure.steps import parse_procedure

#: Free poses recorded, and the pose after which leg 3's encoder reboots.
POSES, REBOOT_AFTER, LEG, SHIFT_MM = 48, 24, 3, 7.0


def _record(path, shift_mm: float):
    """A session of free poses on the mock rig; leg 3's node reboots after pose 24, coming
    back ``shift_mm`` off."""
    hr = hidden_robot(seed=4, effect="gain", scale=0.0)
    proc = parse_procedure(
        "name = 't'\nmodel = 42\n[[steps]]\nid = 'free'\nconstraint = 'free'\n"
        f"instruction = 'move'\nmin_poses = 1\nrecommended_poses = {POSES}\n"
    )
    with mock_rig(hr.truth, seed=4) as rig:
        sf = SessionFile.create(path, Session(robot=hr.design, devices=rig.config))
        with open_rig(rig.config, StillWindow(duration_s=0.1)) as live:
            rig.reproducible(live.acquisition)
            sink = sf.recording_sink(time.monotonic())

            def on_record(kind, step, pose, reason):
                sink(kind, step, pose, reason)
                if kind == "pose" and len(sf.session.poses) == REBOOT_AFTER:
                    rig.nodes.reboot(LEG, zero_shift_mm=shift_mm)

            record_procedure(
                live.acquisition,
                rig.motion,
                proc.expand(),
                float(np.linalg.norm(hr.design.b, axis=1).max()),
                on_record=on_record,
            )
        sf.close()
    return load_session(path)


@pytest.mark.slow
def test_an_encoder_back_7_mm_off_is_marked_flagged_and_named(tmp_path, capsys):
    path = tmp_path / "s.json"
    session = _record(path, SHIFT_MM)
    (mark,) = session.encoder_reboots
    ids = [r.pose_id for r in session.poses]
    # The first pose recorded after the reboot (the sets around it were flagged, those
    # poses refused and taken again).
    assert mark.leg == LEG and mark.pose_id == ids[REBOOT_AFTER]
    # Set-up's check: the reading against the tracker's pose and the design, 7 mm beyond the
    # scatter of the poses before (the drawing's own error from pose to pose: well under 1 mm).
    assert mark.beyond and mark.jump_mm == pytest.approx(SHIFT_MM, abs=0.5)
    assert mark.threshold_mm < 1.0
    note = session.poses[REBOOT_AFTER].notes[-1]
    assert note.startswith(f"leg 3's encoder rebooted before this pose (pose {mark.pose_id})")
    assert "check its zero (re-home, or restore its preset)" in note
    assert all("rebooted" not in n for r in session.poses[:REBOOT_AFTER] for n in r.notes)
    # The diagnosis tests the zero step at that pose first and names it.
    capsys.readouterr()
    # Before any fit, the drawing check blames no offset for the step (Model 42's fit, the
    # step spread over its geometry, may still not match the drawing after it: exit 4).
    assert main(["diagnose", str(path)]) in (0, 4)
    out = capsys.readouterr().out
    assert out.startswith(f"leg 3's encoder rebooted at pose {mark.pose_id}")
    assert (
        f"leg 3's encoder rebooted at pose {mark.pose_id} and came back 7.0 mm off: check its "
        "zero (re-home, or restore its preset); it reads long from there on" in out
    )
    assert main(["diagnose", str(path), "--json"]) in (0, 4)
    (found,) = json.loads(capsys.readouterr().out)["encoder_reboots"]
    # The step's size, refitted, against the 7 mm injected: within 5 µm, 5σ of the estimate
    # (σ = |size|/√χ² without a step: 0.65 µm on the example's 184 poses; ~1 µm on these 48).
    assert found["off"] and found["size_mm"] == pytest.approx(SHIFT_MM, abs=0.005)


@pytest.mark.slow
def test_an_encoder_back_at_its_zero_is_marked_and_not_flagged(tmp_path, capsys):
    """An absolute encoder keeps its zero through a reboot: marked, judged, not flagged."""
    path = tmp_path / "s.json"
    session = _record(path, 0.0)
    (mark,) = session.encoder_reboots
    assert mark.leg == LEG and not mark.beyond and abs(mark.jump_mm) < mark.threshold_mm
    assert "agrees with the tracker's pose and the model" in session.poses[REBOOT_AFTER].notes[-1]
    capsys.readouterr()
    assert main(["diagnose", str(path), "--json"]) == 0
    (found,) = json.loads(capsys.readouterr().out)["encoder_reboots"]
    assert not found["off"] and "came back at its zero" in found["text"]
