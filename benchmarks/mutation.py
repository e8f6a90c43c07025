"""Mutation testing of the core with cosmic-ray (docs/testing.md says why this tool): each
mutant — one operator changed, a constant moved, a comparison flipped — is made in the source
file itself, the tests of that module are run, and the file is restored. A mutant the tests do
not fail on survives; the score is the share killed.

    python benchmarks/mutation.py [--target NAME ...] [--list] [--keep DIR]
        [--sample N [--seed S]] [--marks "not slow"]

Targets (``--list`` prints them with their tests): the drivers' frame decoding and receive path,
io/fileio, the session file, estimate/ module by module, the diagnosis' verdict and scoring, and
the effects' covariates.
Each runs under ``nice -n 10`` on one core, outside CI's time: a mutant costs one pytest start
and its tests (2–30 s), a module a few hundred mutants. Printed: per target the mutants, killed,
survived and incompetent (a mutant that does not run: not counted), the score with its 95 %
Clopper–Pearson interval (a ``--sample`` of a target's mutants estimates its score), and every
survivor with its line — each is then killed by a new test or shown equivalent in
docs/testing.md. Needs ``pip install cosmic-ray`` (not a dependency of hexcal's).

The file under test is modified while a mutant runs: do not edit the tree meanwhile; the script
checks with git that every mutated file is back as it was.
"""

from __future__ import annotations

import argparse
import ast
import functools
import json
import random
import shlex
import subprocess
import sys
import tempfile
from pathlib import Path

from scipy.stats import binomtest

ROOT = Path(__file__).resolve().parents[1]
PYTEST = [sys.executable, "-m", "pytest", "-x", "-q", "-p", "no:cacheprovider", "-m"]
#: The decoding tests of the contract file, by name (its bus tests are not about decoding).
FRAME_TESTS = [
    "tests/test_drivers_can_frames.py",
    "tests/test_drivers_can_encoders.py::test_decode_tpdo_applies_scale_sign_zero",
    "tests/test_drivers_can_encoders.py::test_decode_tpdo_ignores_other_frames_and_rejects_short_ones",
    "tests/test_drivers_can_encoders.py::test_decode_batch_matches_scalar",
    "tests/test_drivers_can_encoders.py::test_describe_error_frames",
]
ESTIMATE = (
    "refine",
    "clamp_rows",
    "calibrate",
    "bound",
    "predict",
    "uncertainty",
    "accuracy",
    "effect_fit",
    "model_file",
    "consistency",
    "quantiles",
    "layout",
    "lm",
    "nbp",
    "leg_rows",
)
#: The estimate modules without a test file of their own name: the tests that call them.
ESTIMATE_TESTS = {
    "lm": ["tests/test_lm.py", "tests/test_refine_solver.py"],
    "nbp": ["tests/test_nbp.py", "tests/test_guided.py"],
    #: test_nbp checks bound's informations against nbp's own Jacobian rows (a Woodbury update).
    "bound": ["tests/test_bound.py", "tests/test_nbp.py"],
    "leg_rows": [
        "tests/test_leg_rows.py",
        "tests/test_refine_solver.py",
        "tests/test_folds.py",
        "tests/test_refine_batch.py",
    ],
    "calibrate": ["tests/test_calibrate.py", "tests/test_refine.py", "tests/test_model_file.py"],
}
#: The diagnosis' wider tests: the sessions with drift, joint effects and zero steps.
DIAGNOSIS_WIDER = [
    "tests/test_drift.py",
    "tests/test_joint_effects.py",
    "tests/test_changepoint.py",
]
#: name → (files to mutate, tests to run); the tests run quick and slow (-m "").
TARGETS: dict[str, tuple[list[str], list[str]]] = {
    "frames": (["drivers/can_frames.py"], FRAME_TESTS),
    "fileio": (["src/hexcal/io/fileio.py"], ["tests/test_fileio.py", "tests/test_strict_json.py"]),
    "session": (
        ["src/hexcal/procedure/session.py"],
        [
            "tests/test_session.py",
            "tests/test_session_lock.py",
            "tests/test_fuzz_sessions.py",
            "tests/test_recording.py",
            "tests/test_sessions_dir.py",
        ],
    ),
    **{
        f"estimate.{m}": (
            [f"src/hexcal/estimate/{m}.py"],
            ESTIMATE_TESTS.get(m, [f"tests/test_{m}.py"]),
        )
        for m in ESTIMATE
    },
    "verdict": (
        ["src/hexcal/diagnosis/verdict.py"],
        [
            "tests/test_verdict.py",
            "tests/test_diagnosis_thresholds.py",
            "tests/test_diagnosis.py",
            *DIAGNOSIS_WIDER,
        ],
    ),
    "scoring": (
        ["src/hexcal/diagnosis/scoring.py"],
        ["tests/test_diagnosis.py", "tests/test_verdict.py", *DIAGNOSIS_WIDER],
    ),
    "covariates": (
        ["src/hexcal/effects/covariates.py"],
        ["tests/test_covariates.py", "tests/test_effect_file.py", "tests/test_explorer.py"],
    ),
    #: The drivers' frame handling: the receive path fed frames directly, and the contract's
    #: tests on python-can's virtual bus (and the one about echoes no interface marks, which
    #: only udp_multicast makes).
    "receive": (
        ["drivers/can_receive.py"],
        [
            "tests/test_drivers_can_receive.py",
            "tests/test_drivers_can_frames.py",
            "tests/test_drivers_can_encoders.py",
            "-k",
            "virtual or own_sync_looped or test_drivers_can_receive",
        ],
    ),
}


#: Where a target is one part of a file: the functions mutated.
FUNCTIONS = {"frames": ("set_nodes", "counts", "decode", "decode_batch", "decode_tpdo")}


def _config(files: list[str], tests: list[str], timeout_s: float, marks: str) -> str:
    command = shlex.join(["nice", "-n", "10", *PYTEST, marks, *tests])
    return (
        "[cosmic-ray]\n"
        f"module-path = {json.dumps(files)}\n"
        f"timeout = {timeout_s}\n"
        "excluded-modules = []\n"
        f"test-command = {json.dumps(command)}\n\n"
        '[cosmic-ray.distributor]\nname = "local"\n'
    )


def _line(path: Path, line: int) -> str:
    return path.read_text().splitlines()[line - 1].strip()


@functools.cache
def _ranges(path: Path, names: tuple[str, ...]) -> list[tuple[int, int]]:
    """The line ranges of the functions ``names`` in ``path``."""
    tree = ast.parse(path.read_text())
    return [
        (n.lineno, n.end_lineno or n.lineno)
        for n in ast.walk(tree)
        if isinstance(n, ast.FunctionDef | ast.AsyncFunctionDef) and n.name in names
    ]


@functools.cache
def _annotations(path: Path) -> list[tuple[tuple[int, int], tuple[int, int]]]:
    """(start, end) (line, column) of every annotation in ``path``: under ``from __future__
    import annotations`` they are strings never evaluated, so a mutant there is equivalent."""
    spans = []
    for n in ast.walk(ast.parse(path.read_text())):
        notes = []
        if isinstance(n, ast.arg) and n.annotation is not None:
            notes.append(n.annotation)
        elif isinstance(n, ast.FunctionDef | ast.AsyncFunctionDef) and n.returns is not None:
            notes.append(n.returns)
        elif isinstance(n, ast.AnnAssign):
            notes.append(n.annotation)
        for a in notes:
            spans.append(
                ((a.lineno, a.col_offset), (a.end_lineno or a.lineno, a.end_col_offset or 0))
            )
    return spans


def _select(db: Path, functions: tuple[str, ...] | None, sample: int | None, seed: int) -> None:
    """Skip (as cosmic-ray's filters do) the mutants outside ``functions``, those in type
    annotations (equivalent: :func:`_annotations`), those replacing an operator by one of
    another family (``a + b`` → ``a << b``: killed by any test, they only inflate the score),
    and all but a random ``sample`` of the rest."""
    from cosmic_ray.work_db import WorkDB, use_db
    from cosmic_ray.work_item import WorkerOutcome, WorkResult

    with use_db(str(db), WorkDB.Mode.open) as wdb:
        keep, skip = [], []
        for item in wdb.pending_work_items:
            m = item.mutations[0]
            inside = functions is None or any(
                a <= m.start_pos[0] <= b for a, b in _ranges(ROOT / m.module_path, functions)
            )
            where = (m.start_pos[0], m.start_pos[1])
            note = any(a <= where < b for a, b in _annotations(ROOT / m.module_path))
            parts = m.operator_name.split("_")
            foreign = parts[0] == "core/ReplaceBinaryOperator" and _family(parts[1]) != _family(
                parts[2]
            )
            key = (str(m.module_path), *m.start_pos, *m.end_pos, m.operator_name, m.occurrence)
            (keep if inside and not foreign and not note else skip).append((key, item.job_id))
        # cosmic-ray lists its work in random order under random ids: sorted by where and what
        # each mutant is, the same --seed draws the same mutants on every run.
        keep.sort()
        ids = [j for _, j in keep]
        skip_ids = [j for _, j in skip]
        if sample is not None and sample < len(ids):
            chosen = set(random.Random(seed).sample(ids, sample))
            skip_ids += [j for j in ids if j not in chosen]
        done = WorkResult(
            output=None, test_outcome=None, diff=None, worker_outcome=WorkerOutcome.SKIPPED
        )
        wdb.set_multiple_results(skip_ids, done)


def _family(op: str) -> str:
    return {"Add": "a", "Sub": "a", "Mul": "m", "Div": "m", "FloorDiv": "m", "Mod": "m"}.get(
        op, "b" if op.startswith("Bit") else op
    )


def run_target(
    name: str,
    work: Path,
    timeout_s: float,
    sample: int | None = None,
    seed: int = 0,
    resume: bool = False,
    marks: str = "",
) -> dict:
    """Mutate ``name``'s files one mutant at a time, run its tests; the tally and survivors."""
    from cosmic_ray.work_db import WorkDB, use_db
    from cosmic_ray.work_item import TestOutcome, WorkerOutcome

    files, tests = TARGETS[name]
    cfg, db = work / f"{name}.toml", work / f"{name}.sqlite"
    cfg.write_text(_config(files, tests, timeout_s, marks))
    cosmic_ray = str(Path(sys.executable).parent / "cosmic-ray")
    if not (resume and db.exists()):  # else go on with the mutants it has not run yet
        subprocess.run([cosmic_ray, "init", str(cfg), str(db)], cwd=ROOT, check=True)
        _select(db, FUNCTIONS.get(name), sample, seed)
    subprocess.run([cosmic_ray, "exec", str(cfg), str(db)], cwd=ROOT, check=True)
    changed = subprocess.run(["git", "diff", "--quiet", "--", *files], cwd=ROOT)
    if changed.returncode:
        raise SystemExit(f"{files} differ from git after the run: restore them (git checkout)")
    tally = {"killed": 0, "survived": 0, "incompetent": 0}
    survivors = []
    with use_db(str(db), WorkDB.Mode.open) as wdb:
        for item, result in wdb.completed_work_items:
            outcome = result.test_outcome
            if outcome == TestOutcome.KILLED:
                tally["killed"] += 1
            elif outcome == TestOutcome.SURVIVED:
                tally["survived"] += 1
                m = item.mutations[0]
                line = m.start_pos[0]
                survivors.append(
                    f"{m.module_path}:{line} {m.operator_name}: {_line(ROOT / m.module_path, line)}"
                )
            elif result.worker_outcome != WorkerOutcome.SKIPPED:
                tally["incompetent"] += 1
    counted = tally["killed"] + tally["survived"]
    return {
        "target": name,
        "sampled": sample,
        "marks": marks,
        **tally,
        "score": tally["killed"] / counted if counted else float("nan"),
        "ci95": score_interval(tally["killed"], counted),
        "survivors": sorted(survivors),
    }


def score_interval(killed: int, counted: int) -> tuple[float, float]:
    """The 95 % Clopper–Pearson interval of the share of a target's mutants the tests kill,
    from ``killed`` of ``counted`` drawn at random (``--sample``); a full run's share is exact,
    and its interval says how far another draw of the same size could fall."""
    if counted == 0:
        return (float("nan"), float("nan"))
    ci = binomtest(killed, counted).proportion_ci(0.95, method="exact")
    return (float(ci.low), float(ci.high))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--target", nargs="*", default=list(TARGETS), choices=list(TARGETS))
    ap.add_argument("--list", action="store_true", help="print the targets and their tests")
    ap.add_argument("--timeout", type=float, default=600.0, help="s per mutant's tests")
    ap.add_argument("--keep", metavar="DIR", help="keep the configs and databases here")
    ap.add_argument("--json", metavar="FILE", help="write the results here too")
    ap.add_argument("--sample", type=int, help="run this many mutants per target, drawn at random")
    ap.add_argument("--seed", type=int, default=0, help="of the --sample draw")
    ap.add_argument(
        "--marks",
        default="",
        help='pytest -m: "" (default) the quick and slow tests, "not slow" the quick ones only',
    )
    ap.add_argument(
        "--resume", action="store_true", help="with --keep: go on with an interrupted run"
    )
    args = ap.parse_args(argv)
    if args.list:
        for name, (files, tests) in TARGETS.items():
            print(f"{name}: {' '.join(files)}  ←  {' '.join(tests)}")
        return 0
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(args.keep or tmp)
        work.mkdir(parents=True, exist_ok=True)
        results = []
        for name in args.target:
            r = run_target(
                name, work, args.timeout, args.sample, args.seed, args.resume, args.marks
            )
            results.append(r)
            lo, hi = r["ci95"]
            print(
                f"{name}: {r['killed'] + r['survived']} mutants, {r['killed']} killed, "
                f"{r['survived']} survived ({r['incompetent']} incompetent, not counted): "
                f"score {100 * r['score']:.1f} % (95 % interval {100 * lo:.0f}–{100 * hi:.0f} %)"
            )
            for s in r["survivors"]:
                print("  survived:", s)
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
