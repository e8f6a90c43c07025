"""Procedure files: the shipped ones load, expand leg by leg, and calibrate what they describe;
a malformed file names the file, the step and the field."""

from __future__ import annotations

import numpy as np
import pytest

from hexcal.estimate.calibrate import calibrate
from hexcal.io.measurements import Measurements
from hexcal.procedure.steps import BUILTIN, ProcedureError, load_procedure, parse_procedure
from hexcal.sim.session_sim import SessionPlan, perturbed_truth
from hexcal.sim.simulate import NoiseModel, Simulator

METHOD = {"direction": "type_i", "direction+length": "type_ii", "length": "type_iii"}


@pytest.mark.parametrize("name", list(BUILTIN))
def test_shipped_procedures_load(name):
    proc = load_procedure(name)
    steps = proc.expand()
    assert steps and all(s.n_poses >= s.min_poses >= 1 for s in steps)
    for s in steps:
        assert "{leg}" not in s.instruction and s.instruction
        if s.leg:
            assert f"leg {s.leg}" in s.instruction


def test_model42_expands_leg_by_leg():
    steps = load_procedure("model42-direction-length").expand()
    assert steps[0].at_home and steps[0].name == "home" and steps[0].n_poses == 1
    steps = steps[1:]
    names = [s.name for s in steps]
    assert names[:4] == [
        "leg1-direction+length",
        "leg1-length",
        "leg2-direction+length",
        "leg2-length",
    ]
    assert names[-1] == "free" and len(names) == 13
    assert steps[0].runs("clamp-length") and steps[0].runs("step-fit")
    assert steps[1].runs("clamp-length") and not steps[1].runs("step-fit")


@pytest.mark.parametrize("name", ["model36-direction", "model42-direction-length"])
def test_each_procedure_calibrates_its_model_on_simulated_data(design, name):
    """Recorded as the procedure says (recommended counts), noise-free, the procedure's own
    model comes back exactly: the procedure asks for enough of the right motions."""
    proc = load_procedure(name)
    truth = perturbed_truth(design, np.random.default_rng(4), SessionPlan())
    sim = Simulator(truth, noise=NoiseModel(0.0, 0.0, 0.0))
    rng = np.random.default_rng(4)
    Ps, Rs, legs, cons = [], [], [], []
    for s in proc.expand():
        P, R = (
            sim.free((s.n_poses,), rng)
            if s.leg == 0
            else getattr(sim, METHOD[s.constraint])(s.leg - 1, (s.n_poses,), rng)
        )
        Ps.append(P), Rs.append(R)
        legs += [s.leg] * s.n_poses
        cons += [s.constraint] * s.n_poses
    P, R = np.concatenate(Ps), np.concatenate(Rs)
    from scipy.spatial.transform import Rotation

    meas = Measurements.from_arrays(
        P,
        Rotation.from_matrix(R),
        sim.readings(P, R),
        leg=np.array(legs),
        constraint=np.array(cons, dtype=object),
    )
    known = design if proc.model == 42 else design.with_geometry(design.a, design.b, truth.offsets)
    cal = calibrate(meas, known, proc.model)
    assert np.allclose(cal.robot.a, truth.a, atol=1e-6)
    assert np.allclose(cal.robot.b, truth.b, atol=1e-6)
    assert np.allclose(cal.robot.offsets, truth.offsets, atol=1e-6)


GOOD_STEP = """
[[steps]]
id = "length"
legs = [1, 2]
constraint = "length"
instruction = "Clamp leg {leg}."
min_poses = 4
recommended_poses = 8
"""


@pytest.mark.parametrize(
    "text, match",
    [
        (
            "name = 'x'\nmodel = 42\n" + GOOD_STEP.replace("min_poses = 4", "min_poses = 0"),
            r"lab\.toml: step 1 \(id 'length'\), field min_poses: Input should be greater than or equal to 1",
        ),
        (
            "name = 'x'\nmodel = 42\n" + GOOD_STEP.replace("[1, 2]", "[1, 7]"),
            r"step 1 \(id 'length'\), field legs: .*legs \[7\] do not exist",
        ),
        (
            "name = 'x'\nmodel = 42\n"
            + GOOD_STEP.replace('"length"\nins', '"direction"\nins').replace(
                "min_poses = 4", "min_poses = 4\nchecks = ['clamp-length']"
            ),
            r"step 1 \(id 'length'\): .*'clamp-length' needs a length clamp",
        ),
        (
            "name = 'x'\nmodel = 40\n" + GOOD_STEP,
            r"lab\.toml: field model: Input should be 36 or 42",
        ),
        (
            "name = 'x'\nmodel = 42\n" + GOOD_STEP + GOOD_STEP,
            r"step ids must be unique; repeated: length",
        ),
        (
            "name = 'x'\nmodel = 42\n" + GOOD_STEP.replace("min_poses", "min_pose"),
            r"step 1 \(id 'length'\), field min_pose: Extra inputs are not permitted",
        ),
        ("name = 'x'\nmodel = 42\n[[steps]\n", r"lab\.toml: not valid TOML"),
        ("name = 'x'\nmodel = 42\nschema = 2\n" + GOOD_STEP, r"field schema: Input should be 1"),
    ],
)
def test_malformed_files_name_file_step_and_field(tmp_path, text, match):
    p = tmp_path / "lab.toml"
    p.write_text(text)
    with pytest.raises(ProcedureError, match=match):
        load_procedure(p)


def test_a_lab_procedure_needs_no_code():
    proc = parse_procedure("name = 'ours'\nmodel = 42\n" + GOOD_STEP, "ours.toml")
    assert [s.name for s in proc.expand()] == ["leg1-length", "leg2-length"]
    with pytest.raises(ProcedureError, match="no such procedure file"):
        load_procedure("/nonexistent/lab.toml")


def test_dots_and_brackets_inside_strings_and_comments_are_not_nesting():
    """The depth scan before tomllib skips strings and comments: a long instruction full of
    dots, brackets and quotes loads."""
    head = (
        "name = 'x'  # a.b.c.d.e.f.g.h.i.j.k.l.m.n.o.p.q.r.s.t.u.v.w.x.y.z.a.b.c.d.e.f.g.h\n"
        "model = 42\n"
        f'description = """\n{"[[{{ a.b. " * 200}\\"""\n"""\n'
        f'reference = "{"a.b." * 100}\\" ]]] "\n'
    )
    instruction = "'" + "1.2.3.[4]." * 50 + "' # [[[[ " + "x." * 40
    text = head + GOOD_STEP.replace('"Clamp leg {leg}."', instruction)
    proc = parse_procedure(text, "dots.toml")
    assert proc.steps[0].instruction.startswith("1.2.3.[4].")
    assert proc.reference.startswith("a.b.a.b.")


@pytest.mark.parametrize(
    ("line", "match"),
    [
        ("tolerance_mm = inf", r"field steps\.0\.tolerance_mm: Infinity is not a finite number"),
        ("tolerance_mm = 11.0", r"field tolerance_mm: Input should be less than or equal to 10"),
        ("x" + ".x" * 40 + " = 1", r"line \d+: a dotted key has more than 32 parts"),
    ],
)
def test_numbers_and_keys_are_bounded(tmp_path, line, match):
    p = tmp_path / "lab.toml"
    p.write_text("name = 'x'\nmodel = 42\n" + GOOD_STEP + line + "\n")
    with pytest.raises(ProcedureError, match=match):
        load_procedure(p)


def test_hexcal_run_offers_every_shipped_procedure():
    from hexcal.app.cli import build_parser
    from hexcal.procedure.steps import BUILTIN

    run = build_parser()._subparsers._group_actions[0].choices["run"]
    choices = next(a.choices for a in run._actions if a.dest == "procedure")
    assert sorted(choices) == sorted(BUILTIN)


def _huge_procedure(steps: int, poses: int) -> str:
    """A procedure of ``steps`` free steps of ``poses`` poses each (the campaign's: 2,000 ×
    10,000, 20 million poses in a ~200 KB file)."""
    one = (
        "[[steps]]\nid = 's{i}'\nconstraint = 'free'\ninstruction = 'move'\n"
        f"min_poses = 1\nrecommended_poses = {poses}\n"
    )
    return "name = 'huge'\nmodel = 42\n" + "".join(one.format(i=i) for i in range(steps))


def test_a_procedure_beyond_what_a_session_holds_is_refused_naming_total_and_cap(tmp_path):
    from hexcal.io.capacity import MAX_PROCEDURE_POSES

    p = tmp_path / "huge.toml"
    p.write_text(_huge_procedure(2000, 10_000))
    with pytest.raises(ProcedureError) as exc:
        load_procedure(p)
    text = str(exc.value)
    assert text.startswith(f"{p}: the procedure asks for 20,000,000 poses in all (2,000 steps")
    assert f"a session holds at most {MAX_PROCEDURE_POSES:,} recorded poses" in text
    # Legs count: 7 clamped steps over 6 legs at the cap's share stay within it, one more not.
    per = MAX_PROCEDURE_POSES // 6 // 7
    step = (
        "[[steps]]\nid = 'c{i}'\nlegs = [1, 2, 3, 4, 5, 6]\nconstraint = 'direction'\n"
        f"instruction = 'clamp'\nmin_poses = 4\nrecommended_poses = {per}\n"
    )
    head = "name = 'legs'\nmodel = 42\n"
    assert len(parse_procedure(head + "".join(step.format(i=i) for i in range(7))).expand())
    with pytest.raises(ProcedureError, match=r"asks for [\d,]+ poses in all \(48 steps"):
        parse_procedure(head + "".join(step.format(i=i) for i in range(8)), "legs.toml")


def test_the_operators_pose_counts_are_held_to_the_same_caps(tmp_path, capsys):
    """``--poses-per-step`` takes the procedure file's per-step cap (10,000), and counts that
    add up to more than a session holds are refused before anything is recorded."""
    from hexcal.app.cli import main
    from hexcal.app.workflow import procedure_steps
    from hexcal.io.capacity import MAX_POSES_PER_STEP

    session = tmp_path / "s.json"
    for option in ("--poses-per-step", "--free-poses"):
        args = ["demo", option, str(MAX_POSES_PER_STEP + 1), "--session", str(session)]
        with pytest.raises(SystemExit) as exc:
            main(args)
        assert exc.value.code == 2
        assert f"10001 is outside [{0 if option == '--free-poses' else 1}, 10000]" in (
            capsys.readouterr().err
        )
    proc = parse_procedure(_huge_procedure(10, 10))
    assert sum(s.n_poses for s in procedure_steps(proc, None, 4000)) == 40_000
    with pytest.raises(ProcedureError, match=r"these pose counts ask for 50,000 poses in all"):
        procedure_steps(proc, None, 5000)
    p = tmp_path / "huge.toml"
    p.write_text(_huge_procedure(2000, 10_000))
    assert main(["demo", "--procedure", str(p), "--session", str(session)]) == 2
    assert "20,000,000 poses in all" in capsys.readouterr().err
    assert not session.exists()
    # The text UI's: 12 clamped steps at the cap, home and 30 free poses, before it starts.
    assert main(["run", "--mock", "--poses-per-step", "10000", "--session", str(session)]) == 2
    assert "these pose counts ask for 120,031 poses in all (14 steps" in capsys.readouterr().err
    assert not session.exists()
