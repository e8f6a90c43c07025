"""The mutated-file corpus through the command line: no traceback, no run over 30 s, no
non-strict JSON.

    python benchmarks/bad_input_corpus.py [--cases 4000] [--workers 2] [--seed 0] [--json]

Each case takes a valid input — the measurement table, robot.json, instruments.json, a
session file, a lab's log or its mapping (from examples/ and tests/data/) — mutates it the
way files go wrong (a value replaced by NaN, Infinity, 1e308, a huge integer, true, null, a
string or deep nesting; a key given twice, removed or added; a row repeated, a column removed,
swapped or scaled; quaternions reordered, a reading's sign flipped, readings or positions in
cm; semicolons and decimal commas; a byte-order mark, CRLF, a byte that is not UTF-8, a cut;
for robot.json, a stroke the readings may lie beyond) and runs the command that reads it,
in-process through ``hexcal.app.cli.main`` as the console script does: ``calibrate --json``
(table, robot, instruments, session), ``validate --json`` (a mutated calibrated.json),
``session export`` (session), ``import`` (log, mapping). Case ``i`` is drawn from
``random.Random(seed * 1_000_003 + i)``: any case reruns alone with ``--only i``. Besides, an
imported session's pose block is damaged each way of :data:`BLOCK_DAMAGES` (cut short, a bit
of its records flipped, a wrong header, missing, counted beyond the session's limit, longer)
and read by ``calibrate --json`` and ``session export``: each must be refused with exit 2
and a message naming the block file.

A case fails when: the exit status is 1 (hexcal's "internal error": an exception no message
was written for) or the command raised; stderr holds a traceback; the run took over 30 s of
CPU (its wall time is printed too: on a shared machine it is inflated by the others' load); or
a ``--json`` run printed text that a strict parser (no NaN, no Infinity) refuses. Printed: the
cases per input kind, the exit statuses, the slowest runs, and every failure with its case
number. ``--workers`` processes share the cases (at most 2 on a shared machine).
"""

# ruff: noqa: E402  (the BLAS thread count is set before numpy is imported)
from __future__ import annotations

from hexcal.app.cli import single_thread_blas

single_thread_blas()

import argparse
import contextlib
import csv
import io
import json
import multiprocessing as mp
import random
import statistics
import sys
import tempfile
import time
import traceback
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "left-hand-sim"
JUGGLEBOT = ROOT / "examples" / "jugglebot"
LIMIT_S = 30.0
KINDS = ("table", "robot", "instruments", "session", "model", "log", "map")

JSON_TOKENS = ["NaN", "Infinity", "-Infinity", "1e308", "1e400", "-0", "0", "-1", "1000001",
               "9007199254740993", "1" * 400, '"x"', '""', "null", "true", "false", "[]", "{}",
               "[1, 2]", "[" * 40 + "]" * 40, '{"a": ' * 40 + "1" + "}" * 40]  # fmt: skip
CSV_TOKENS = ["NaN", "inf", "1e308", "1e400", "-0", "", " ", "x", "1_000", "3.0", "+5", "1e6",
              "9007199254740992", "12,5", '"', "free", "Direction", "length", "7"]  # fmt: skip
TOML_TOKENS = ["nan", "inf", "1e400", "-1", "0", "true", '"x"', "[]", "{}", "99999999999999999999",
               "[1, nan]", "[" * 40 + "]" * 40]  # fmt: skip
#: Strokes (leg_range_mm) given to robot.json: the example's readings lie within the second,
#: 300 mm past the third, in cm against the fourth; the first cuts them, the last is generous.
STROKES = [[0.0, 100.0], [-5.0, 115.0], [-400.0, -300.0], [-0.5, 11.5], [-1000.0, 1000.0]]
BAD_BYTES = [b"\x96", b"\xff", b"\xc3", b"\x00"]


# -- the valid inputs ---------------------------------------------------------------------------
def _head(path: Path, rows: int) -> str:
    return "".join(path.read_text(encoding="utf-8").splitlines(keepends=True)[: rows + 1])


def valid_inputs(folder: Path) -> dict[str, Path]:
    """The valid files the mutations start from, in ``folder``."""
    from hexcal.estimate.model_file import load_robot
    from hexcal.io.measurements_csv import read_measurements
    from hexcal.procedure.session import Session, SessionFile

    files = {
        "table": folder / "measurements.csv",
        "robot": EXAMPLE / "robot.json",
        "instruments": EXAMPLE / "instruments.json",
        "model": ROOT / "tests" / "data" / "calibrated.json",
        "log": folder / "log.csv",
        "map": ROOT / "examples" / "jugglebot" / "map.toml",
        "session": folder / "session.json",
    }
    # 80 poses: every leg's clamped steps and free poses, and a calibration in about a second.
    files["table"].write_text(_head(EXAMPLE / "measurements.csv", 80), encoding="utf-8")
    files["log"].write_text(_head(JUGGLEBOT / "108_calibration_poses.csv", 60), encoding="utf-8")
    meas = read_measurements(files["table"])
    with SessionFile.create(
        files["session"], Session.from_measurements(meas, load_robot(files["robot"]))
    ):
        pass
    # The same table imported: its poses in a pose block beside the session file.
    files["imported"] = folder / "imported.json"
    SessionFile.create(files["imported"], Session.with_table(meas, load_robot(files["robot"])))
    return files


# -- mutations ---------------------------------------------------------------------------------
def _encoding(rng: random.Random, text: str) -> bytes:
    if rng.random() < 0.15:
        text = text.replace("\n", rng.choice(["\r\n", "\r"]))
    data = text.encode("utf-8")
    if rng.random() < 0.1:
        data = b"\xef\xbb\xbf" + data
    if rng.random() < 0.08:
        at = rng.randrange(len(data) + 1)
        data = data[:at] + rng.choice(BAD_BYTES) + data[at:] if rng.random() < 0.5 else data[:at]
    return data


def _paths(node, path=()):
    out = [path]
    if isinstance(node, dict):
        for k, v in node.items():
            out += _paths(v, (*path, k))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            out += _paths(v, (*path, i))
    return out


def mutate_json(rng: random.Random, text: str) -> bytes:
    data = json.loads(text)
    marker = "@@token@@"
    dup = None
    for _ in range(rng.randint(1, 3)):
        path = rng.choice(_paths(data))
        if not path:
            continue
        parent = data
        for p in path[:-1]:
            parent = parent[p]
        op = rng.choice(["replace"] * 4 + ["delete", "add", "duplicate"])
        if op == "replace":
            parent[path[-1]] = marker
        elif op == "delete":
            del parent[path[-1]]
        elif op == "add" and isinstance(parent, dict):
            parent[rng.choice(["extra", "schema_version", "pose_id", "units"])] = marker
        elif op == "duplicate" and isinstance(parent, dict):
            dup = path[-1]
    out = json.dumps(data, indent=rng.choice([None, 1]))
    while f'"{marker}"' in out:
        out = out.replace(f'"{marker}"', rng.choice(JSON_TOKENS), 1)
    if dup is not None and f'"{dup}":' in out:  # the key given twice, as a hand edit leaves it
        at = out.index(f'"{dup}":')
        out = out[:at] + f'"{dup}": {rng.choice(JSON_TOKENS)}, ' + out[at:]
    return _encoding(rng, out)


def _table_rows(text: str) -> list[list[str]]:
    return list(csv.reader(io.StringIO(text)))


def _semantic(rng: random.Random, rows: list[list[str]], kind: str) -> list[list[str]]:
    """The slips of a whole table: columns reordered, scaled, flipped (what the data's own
    consistency check names)."""
    h = rows[0]
    col = {name: i for i, name in enumerate(h)}
    rho = [c for c in h if c.startswith("rho") or c.startswith("leg_length")]
    q = [c for c in h if c in ("qw", "qx", "qy", "qz")] or [c for c in h if "orientation" in c]
    pos = [c for c in h if c in ("x", "y", "z") or c.startswith("position")]
    op = rng.choice(["swap", "flip", "scale", "quaternion", "positions", "header-swap"])
    body = rows[1:]
    if op == "swap" and len(rho) >= 2:
        a, b = rng.sample(rho, 2)
        for r in body:
            r[col[a]], r[col[b]] = r[col[b]], r[col[a]]
    elif op == "flip" and rho:
        c = col[rng.choice(rho)]
        for r in body:
            r[c] = repr(-float(r[c])) if _number(r[c]) else r[c]
    elif op in ("scale", "positions"):
        factor = rng.choice([0.1, 10.0, 1 / 25.4, 0.001])
        for r in body:
            for name in rho if op == "scale" else pos + rho:
                c = col[name]
                r[c] = repr(float(r[c]) * factor) if _number(r[c]) else r[c]
    elif op == "quaternion" and len(q) == 4:
        idx = [col[c] for c in q]
        for r in body:
            vals = [r[i] for i in idx]
            for i, v in zip(idx, vals[1:] + vals[:1], strict=True):
                r[i] = v
    elif op == "header-swap" and len(h) > 2:
        i, j = rng.sample(range(len(h)), 2)
        h[i], h[j] = h[j], h[i]
    return rows


def _number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def mutate_csv(rng: random.Random, text: str, kind: str) -> bytes:
    rows = _table_rows(text)
    if rng.random() < 0.25:
        rows = _semantic(rng, rows, kind)
    else:
        for _ in range(rng.randint(1, 3)):
            op = rng.choice(["cell"] * 6 + ["column", "row", "add-column"])
            i = rng.randrange(len(rows))
            if op == "cell" and rows[i]:
                rows[i][rng.randrange(len(rows[i]))] = rng.choice(CSV_TOKENS)
            elif op == "column" and rows[0]:
                j = rng.randrange(len(rows[0]))
                rows = [r[:j] + r[j + 1 :] for r in rows]
            elif op == "row":
                rows.insert(i, list(rows[i]))
            else:
                rows = [[*r, rng.choice(CSV_TOKENS)] for r in rows]
    sep = ","
    if rng.random() < 0.1:  # a spreadsheet's export: semicolons, often decimal commas
        sep = ";"
        if rng.random() < 0.6:
            rows = [rows[0]] + [[c.replace(".", ",") for c in r] for r in rows[1:]]
    out = "\n".join(sep.join(r) for r in rows) + "\n"
    return _encoding(rng, out)


def mutate_toml(rng: random.Random, text: str) -> bytes:
    lines = text.split("\n")
    for _ in range(rng.randint(1, 3)):
        i = rng.randrange(len(lines))
        line = lines[i]
        op = rng.choice(["value"] * 3 + ["delete", "copy", "insert"])
        if op == "value" and "=" in line and not line.lstrip().startswith("#"):
            lines[i] = line.split("=", 1)[0] + "= " + rng.choice(TOML_TOKENS)
        elif op == "delete":
            del lines[i]
        elif op == "copy":
            lines.insert(i, line)  # a key given twice
        else:
            lines.insert(i, rng.choice(["extra = 1", "[extra]", "[pose]", "x.y.z = nan"]))
        if not lines:
            lines = [""]
    return _encoding(rng, "\n".join(lines))


# -- one case ------------------------------------------------------------------------------------
def make_case(
    i: int, seed: int, files: dict[str, Path], folder: Path
) -> tuple[str, list[str], bool]:
    """(kind, the command's arguments, whether it prints JSON) of case ``i``, its mutated file
    written into ``folder``."""
    rng = random.Random(seed * 1_000_003 + i)
    kind = KINDS[i % len(KINDS)]
    src = files[kind]
    text = src.read_text(encoding="utf-8")
    if kind == "robot" and rng.random() < 0.3:  # a stroke the readings may lie beyond
        text = json.dumps(json.loads(text) | {"leg_range_mm": rng.choice(STROKES)})
    suffix = {"table": ".csv", "log": ".csv", "map": ".toml"}.get(kind, ".json")
    path = folder / f"case{i}{suffix}"
    if kind in ("table", "log"):
        data = mutate_csv(rng, text, kind)
    elif kind == "map":
        data = mutate_toml(rng, text)
    else:
        data = mutate_json(rng, text)
    path.write_bytes(data)
    f = {k: str(v) for k, v in files.items()}
    out = str(folder / f"out{i}")
    if kind == "table":
        args = ["calibrate", str(path), "--robot", f["robot"], "--instruments", f["instruments"]]
    elif kind == "robot":
        args = ["calibrate", f["table"], "--robot", str(path), "--instruments", f["instruments"]]
    elif kind == "instruments":
        args = ["calibrate", f["table"], "--robot", f["robot"], "--instruments", str(path)]
    elif kind == "session":
        if rng.random() < 0.3:
            return kind, ["session", "export", str(path), "--out", out], False
        args = ["calibrate", str(path)]
    elif kind == "model":
        return kind, ["validate", str(path), f["table"], "--json"], True
    elif kind == "log":
        return kind, ["import", str(path), "--map", f["map"], "--out", out + ".csv"], False
    else:
        return kind, ["import", f["log"], "--map", str(path), "--out", out + ".csv"], False
    if rng.random() < 0.3:
        args.append("--lengths-only")
    if rng.random() < 0.15:
        args.append("--no-drawing-check")
    return kind, [*args, "--json"], True


# -- a damaged pose block -------------------------------------------------------------------------
def damage_block(damage: str, rng: random.Random, imported: Path, folder: Path) -> Path:
    """A copy of the ``imported`` session whose pose block is damaged as ``damage`` says: cut
    short, a bit of its records flipped, its header wrong, missing, counted beyond the
    session's limit by the session file, or longer. The block's path (the session file is
    ``<block>.json``)."""
    from hexcal.io import capacity
    from hexcal.io.pose_block import HEADER_BYTES

    doc = json.loads(imported.read_text(encoding="utf-8"))
    data = imported.with_name(doc["pose_block"]["file"]).read_bytes()
    block = folder / f"block-{damage}.poses.npy"
    doc["pose_block"]["file"] = block.name
    if damage == "truncated":
        data = data[: rng.randrange(len(data))]
    elif damage == "bit-flipped":  # in the records, which the session file's checksum covers
        at = rng.randrange(HEADER_BYTES, len(data))
        data = data[:at] + bytes([data[at] ^ (1 << rng.randrange(8))]) + data[at + 1 :]
    elif damage == "wrong-header":
        head = data[:HEADER_BYTES]
        wrong = rng.choice([
            b"\x93NUMPY\x02\x00" + head[8:],  # another .npy version
            head[:8] + b"\x00\x01" + head[10:],  # another header length
            head.replace(b"'<f8'", b"'<f4'", 1),  # another record
            head.replace(b"'shape': (", b"'shape': (1", 1),  # another count
            head.replace(b"False", b"True", 1),  # Fortran order
            bytes(HEADER_BYTES),  # zeros
        ])  # fmt: skip
        data = wrong + data[HEADER_BYTES:]
    elif damage == "over-the-limit":
        doc["pose_block"]["poses"] = capacity.MAX_IMPORTED_POSES + 1
    elif damage == "longer":
        data += bytes(rng.randrange(1, 300))
    if damage != "missing":
        block.write_bytes(data)
    block.with_suffix(".json").write_text(json.dumps(doc), encoding="utf-8")
    return block


#: The ways a session's pose block is damaged, each run through every command of a session.
BLOCK_DAMAGES = ("truncated", "bit-flipped", "wrong-header", "missing", "over-the-limit", "longer")


def block_cases(seed: int, files: dict[str, Path], folder: Path) -> list[dict]:
    """Every damage of :data:`BLOCK_DAMAGES` through ``calibrate --json`` and ``session
    export``: each must be refused (exit 2) naming the block file, besides the corpus's rules."""
    results = []
    for k, damage in enumerate(BLOCK_DAMAGES):
        rng = random.Random(seed * 1_000_003 + k)
        block = damage_block(damage, rng, files["imported"], folder)
        session = str(block.with_suffix(".json"))
        for args, wants_json in (
            (["calibrate", session, "--json"], True),
            (["session", "export", session, "--out", str(folder / f"out-{damage}")], False),
        ):
            r = run_case(args, wants_json, names=str(block))
            results.append({"case": f"block {damage}", "kind": "block", "args": args[0], **r})
    return results


def run_case(args: list[str], wants_json: bool, names: str = "") -> dict:
    """Run one command in-process; what a user would see judged."""
    from hexcal.app.cli import main
    from hexcal.io.json_out import loads_strict

    out, err = io.StringIO(), io.StringIO()
    t0, c0 = time.perf_counter(), time.process_time()
    problem = ""
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            code = main(args)
    except SystemExit as exc:  # argparse
        code = exc.code if isinstance(exc.code, int) else 2
    except BaseException:
        code = -1
        problem = "raised: " + traceback.format_exc(limit=3).strip().splitlines()[-1]
    elapsed = time.perf_counter() - t0
    cpu = time.process_time() - c0
    stderr = err.getvalue()
    if code == 1:
        problem = problem or "exit 1 (internal error): " + stderr.strip()[:300]
    elif names and (code != 2 or names not in stderr):
        problem = f"exit {code}, not refused naming {names}: " + stderr.strip()[:300]
    elif "Traceback" in stderr:
        problem = "a traceback on stderr"
    elif cpu > LIMIT_S:
        problem = f"took {cpu:.1f} s of CPU ({elapsed:.1f} s wall)"
    elif wants_json and out.getvalue().strip():
        try:
            loads_strict(out.getvalue())
        except ValueError as exc:
            problem = f"stdout is not strict JSON ({exc})"
    return {"code": code, "s": elapsed, "cpu_s": cpu, "problem": problem}


def _work(job: tuple[list[int], int, bool]) -> list[dict]:
    indices, seed, blocks = job
    results = []
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        files = valid_inputs(folder)
        # First: a case's files are removed by its number, which the block's name may hold.
        results += block_cases(seed, files, folder) if blocks else []
        for i in indices:
            kind, args, wants_json = make_case(i, seed, files, folder)
            r = run_case(args, wants_json)
            results.append({"case": i, "kind": kind, "args": " ".join(args[:1]), **r})
            for p in folder.glob(f"*{i}*"):  # the case's own files
                if p.is_file():
                    p.unlink()
    return results


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--cases", type=int, default=4000)
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--only", type=int, help="run this one case and show its output")
    p.add_argument("--json", action="store_true")
    opts = p.parse_args()
    if opts.only is not None:
        with tempfile.TemporaryDirectory() as tmp:
            files = valid_inputs(Path(tmp))
            kind, args, _ = make_case(opts.only, opts.seed, files, Path(tmp))
            print(kind, " ".join(args))
            from hexcal.app.cli import main as hexcal_main

            return hexcal_main(args)
    t0 = time.perf_counter()
    chunks = [
        (list(range(w, opts.cases, opts.workers)), opts.seed, w == 0) for w in range(opts.workers)
    ]
    if opts.workers > 1:
        with mp.get_context("spawn").Pool(opts.workers) as pool:
            results = [r for part in pool.map(_work, chunks) for r in part]
    else:
        results = _work(chunks[0])
    wall = time.perf_counter() - t0
    failures = [r for r in results if r["problem"]]
    times = sorted(results, key=lambda r: -r["s"])
    summary = {
        "cases": len(results),
        "by_kind": dict(Counter(r["kind"] for r in results)),
        "exit_statuses": {str(k): v for k, v in sorted(Counter(r["code"] for r in results).items())},
        "failures": len(failures),
        "tracebacks": sum("raised" in r["problem"] or "traceback" in r["problem"] or "exit 1" in r["problem"] for r in failures),
        "over_30_s_cpu": sum(r["cpu_s"] > LIMIT_S for r in results),
        "over_30_s_wall": sum(r["s"] > LIMIT_S for r in results),
        "slowest_cpu_s": sorted((round(r["cpu_s"], 2) for r in results), reverse=True)[:5],
        "non_strict_json": sum("strict JSON" in r["problem"] for r in failures),
        "slowest_s": [round(r["s"], 2) for r in times[:5]],
        "slowest_cases": [r["case"] for r in times[:5]],
        "median_s": round(statistics.median(r["s"] for r in results), 3),
        "wall_s": round(wall, 1),
        "seed": opts.seed,
        "failed_cases": [{k: r[k] for k in ("case", "kind", "args", "problem")} for r in failures[:50]],
    }  # fmt: skip
    if opts.json:
        print(json.dumps(summary, indent=2))
    else:
        for key, value in summary.items():
            if key != "failed_cases":
                print(f"{key}: {value}")
        for f in summary["failed_cases"]:
            print(f"  case {f['case']} ({f['kind']}, {f['args']}): {f['problem']}")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
