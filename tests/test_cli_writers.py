"""Every writer of the command line on a full disk and under a file-size limit (``ulimit -f``):
one message naming the user's path, no traceback, and nothing left behind — no partial file,
no temporary file, no empty folder, no lone file of a set, no stale lock.

The full disk is a tmpfs mounted for the test (root only; skipped elsewhere) and filled to
``free`` bytes; the file-size limit is ``RLIMIT_FSIZE`` set in the child before it runs. Each
command runs as the console script runs, in a process of its own."""

from __future__ import annotations

import csv
import os
import resource
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "left-hand-sim"
JUGGLEBOT = ROOT / "examples" / "jugglebot"
M, R = str(EXAMPLE / "measurements.csv"), str(EXAMPLE / "robot.json")

pytestmark = pytest.mark.slow


def _hexcal(args: list[str], fsize: int | None = None) -> subprocess.CompletedProcess:
    def limit() -> None:
        if fsize is not None:
            resource.setrlimit(resource.RLIMIT_FSIZE, (fsize, fsize))

    return subprocess.run(
        [sys.executable, "-m", "hexcal.app.cli", *args],
        capture_output=True,
        text=True,
        preexec_fn=limit,
        timeout=600,
    )


@pytest.fixture(scope="module")
def inputs(tmp_path_factory) -> Path:
    """A calibrated model, two sessions and a readings table to write from."""
    d = tmp_path_factory.mktemp("inputs")
    for args in (
        ["calibrate", M, "--robot", R, "--out", str(d / "cal.json")],
        ["session", "import", M, "--robot", R, "--out", str(d / "s.json")],
        ["session", "import", M, "--robot", R, "--out", str(d / "s2.json")],
    ):
        assert _hexcal(args).returncode == 0
    with open(M, newline="") as f:
        rows = list(csv.DictReader(f))[:50]
    with open(d / "readings.csv", "w") as f:
        f.write("rho1,rho2,rho3,rho4,rho5,rho6\n")
        f.writelines(",".join(r[f"rho{k}"] for k in range(1, 7)) + "\n" for r in rows)
    return d


def _writers(d: Path, inp: Path) -> dict[str, tuple[list[str], str]]:
    """Each writer: its arguments writing into ``d``, and the path its message must name."""
    return {
        "calibrate --out": (["calibrate", M, "--robot", R, "--out", f"{d}/cal.json"], "cal.json"),
        "diagnose --plots": (["diagnose", M, "--robot", R, "--plots", f"{d}/plots"], "plots/"),
        "diagnose --report": (["diagnose", M, "--robot", R, "--report", f"{d}/r.html"], "r.html"),
        "diagnose --residuals": (
            ["diagnose", M, "--robot", R, "--residuals", f"{d}/res.csv"],
            "res.csv",
        ),
        "diagnose --out": (["diagnose", M, "--robot", R, "--out", f"{d}/cal.json"], "cal.json"),
        "import": (
            [
                "import",
                str(JUGGLEBOT / "108_calibration_poses.csv"),
                "--map",
                str(JUGGLEBOT / "map.toml"),
                "--out",
                f"{d}/m.csv",
            ],
            "m.csv",
        ),
        "predict --out": (
            ["predict", str(inp / "cal.json"), str(inp / "readings.csv"), "--out", f"{d}/p.csv"],
            "p.csv",
        ),
        "export linuxcnc": (
            # The homing said and the drawing's home carried over (the export asks for both).
            ["export", "linuxcnc", str(inp / "cal.json"), "--out", f"{d}/lx"]
            + ["--encoders", "absolute", "--drawing", R],
            "lx/",
        ),
        "export table": (["export", "table", str(inp / "cal.json"), "--out", f"{d}/tab"], "tab/"),
        "simulate": (["simulate", "--out", f"{d}/sim"], "sim/"),
        "session import": (
            ["session", "import", M, "--robot", R, "--out", f"{d}/s.json"],
            "s.json",
        ),
        "session export": (["session", "export", str(inp / "s.json"), "--out", f"{d}/exp"], "exp/"),
        "session merge": (
            [
                "session",
                "merge",
                str(inp / "s.json"),
                str(inp / "s2.json"),
                "--out",
                f"{d}/mg.json",
            ],
            "mg.json",
        ),
        "examples": (["examples", "--out", f"{d}/ex"], "ex/"),
    }


WRITERS = list(_writers(Path("."), Path(".")))


def _check(proc: subprocess.CompletedProcess, d: Path, names: str, before: set[Path]) -> None:
    left = sorted(str(p.relative_to(d)) for p in d.rglob("*") if p not in before)
    if proc.returncode == 0:  # it fitted: then it is whole (nothing to check here)
        return
    assert proc.returncode == 2, proc.stderr
    assert "Traceback" not in proc.stderr, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) >= 1 and lines[-1].startswith(f"hexcal: {d}/{names}"), proc.stderr
    assert left == [], (left, proc.stderr)


@pytest.mark.parametrize("limit", [512, 60_000])
@pytest.mark.parametrize("writer", WRITERS)
def test_under_a_file_size_limit(tmp_path, inputs, writer, limit):
    args, names = _writers(tmp_path, inputs)[writer]
    proc = _hexcal(args, limit)
    if limit == 512:  # every writer's output is larger: each must fail
        assert proc.returncode != 0, f"{writer} wrote under a 512-byte limit"
        assert "file-size limit, ulimit -f" in proc.stderr, proc.stderr
    _check(proc, tmp_path, names, set())


@pytest.fixture
def full_disk(tmp_path):
    """A 400 KB tmpfs, filled to ``free`` bytes by a call to the fixture's value."""
    d = tmp_path / "disk"
    d.mkdir()
    if os.geteuid() != 0 or shutil.which("mount") is None:
        pytest.skip("mounting a tmpfs needs root")
    if subprocess.run(["mount", "-t", "tmpfs", "-o", "size=400k", "tmpfs", str(d)]).returncode:
        pytest.skip("no tmpfs can be mounted here")

    def fill(free: int) -> set[Path]:
        with open(d / "filler", "wb", buffering=0) as f:
            try:
                while True:
                    f.write(b"\0" * 4096)
            except OSError:
                pass
        if free:
            os.truncate(d / "filler", max(0, (d / "filler").stat().st_size - free))
        return {d / "filler"}

    yield d, fill
    subprocess.run(["umount", str(d)])


@pytest.mark.parametrize("free", [0, 2048, 60_000])
@pytest.mark.parametrize("writer", WRITERS)
def test_on_a_full_disk(full_disk, inputs, writer, free):
    d, fill = full_disk
    args, names = _writers(d, inputs)[writer]
    before = fill(free)
    proc = _hexcal(args)
    if free == 0:
        assert proc.returncode != 0, f"{writer} wrote on a full disk"
        assert "the disk is full" in proc.stderr, proc.stderr
    _check(proc, d, names, before)
