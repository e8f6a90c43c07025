"""The README's table of how often the diagnosis is right, generated from the full run's output
(docs/diagnosis_rates.json, written by diagnosis_rates.py), never typed in.

    python benchmarks/rates_readme.py [--json docs/diagnosis_rates.json] [--write]

Prints the table; ``--write`` puts it in README.md in place of the one there (the lines from
its header to the blank line after it). tests/test_rates.py checks that README.md holds this
table and docs/diagnosis.md the full one (diagnosis_rates.markdown) of the same file.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
HEADER = "| hidden in the session | named right | error after adding it within 15 % of the floor |"
EFFECTS = ("offset", "gain", "backlash", "thermal", "compliance", "leadscrew", "drift")
CLEAN = ("clean", "precision: clean", "motion base: clean")
FOREIGN = ("stroke quadratic", "stroke dent", "joint play")


def _pct(x: float) -> str:
    return f"{100 * x:.0f} %"


def _span(values: list[float]) -> str:
    """One percentage, or the lowest–highest."""
    lo, hi = min(values), max(values)
    return _pct(lo) if round(100 * lo) == round(100 * hi) else f"{100 * lo:.0f}–{_pct(hi)}"


def readme_table(s: dict) -> str:
    """The README's summary table from ``s``, the full run's summary."""

    def get(keys, field="right"):
        return [s[k][field] for k in keys]

    def each(keys, field="right"):
        return " / ".join(_pct(v) for v in get(keys, field))

    joints = ("ujoint (1 mm)", "balljoint (1 mm)")
    below = ("ujoint (0.15 mm)", "balljoint (0.035 mm)")
    alarms = round(sum(s[k]["false_alarms"] * s[k]["sessions"] for k in CLEAN))
    jump, noise, three = s["zero jump"], s["noise understated"], s["three effects"]
    rows = [
        (
            "each catalogue effect at its realistic size (offset, gain, backlash, thermal, "
            "compliance, lead screw, drift)",
            _span(get(EFFECTS)),
            _span(get(EFFECTS, "after_within_15pct")),
        ),
        (
            "the joints' axes 1 mm apart: `ujoint` / `balljoint`",
            each(joints),
            each(joints, "after_within_15pct"),
        ),
        (
            "the joints' axes below detection (0.15 mm, 0.035 mm)",
            f"`none` in {_span(get(below))}",
            "—",
        ),
        (
            "nothing, on each of the three simulated robots",
            f"`none` in {_span(get(CLEAN))} ({alarms} false alarms)",
            "—",
        ),
        (
            "gain, thermal and backlash at once (`--auto`)",
            f"`none` reached in {_pct(three['right'])}",
            _pct(three["after_within_15pct"]),
        ),
        (
            "only what the geometry absorbs (a tracker scale, leg sag)",
            f"`none` in {each(('tracker scale', 'leg sag'))}",
            "—",
        ),
        (
            "one leg's zero jumping 50 µm mid-session",
            f"{_pct(jump['right'])}, located within ±3 poses in {_pct(jump['located'])}",
            _pct(jump["after_within_15pct"]),
        ),
        (
            "stated noise 2× too low",
            f"{_pct(noise['right'])}, factor within 20 % in {_pct(noise['factor_within_20pct'])}",
            "—",
        ),
        (
            "outside the catalogue: quadratic encoder error / a dent / joint play (`--auto`)",
            f"the right covariate in {_span(get(FOREIGN, 'named_right'))}",
            f"{each(FOREIGN, 'after_within_15pct')} (with the effect file it writes)",
        ),
    ]
    lines = [HEADER, "|---|---|---|"] + [f"| {a} | {b} | {c} |" for a, b, c in rows]
    return "\n".join(lines)


def replace_table(readme: str, table: str) -> str:
    """``readme`` with the table that starts at :data:`HEADER` replaced by ``table``."""
    start = readme.index(HEADER)
    end = readme.find("\n\n", start)
    end = len(readme) if end < 0 else end
    return readme[:start] + table + readme[end:]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--json", default=str(ROOT / "docs" / "diagnosis_rates.json"))
    ap.add_argument("--write", action="store_true", help="replace the table in README.md")
    args = ap.parse_args(argv)
    table = readme_table(json.loads(Path(args.json).read_text())["summary"])
    print(table)
    if args.write:
        path = ROOT / "README.md"
        path.write_text(replace_table(path.read_text(), table))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
