"""The outputs the docs quote, made by the code as it is today from the shipped examples and the
walkthrough's sessions — one script, so a quote cannot drift from what hexcal prints:

- in README.md and docs/diagnosis.md, between cog's markers (``[[[cog …]]]`` … ``[[[end]]]``,
  inside HTML comments), the blocks the functions below print: the walkthrough's table and
  abridged output, the Jugglebot's headline, verdict chain and scales;
- the walkthrough's whole outputs, :data:`TEXT_FILES` (docs/walkthrough/*.txt);
- the walkthrough's report and its screenshots (written, not checked: :func:`report`).

    python docs/quoted.py          # write them all anew
    python docs/quoted.py --check  # exit 1, with a diff, where a quote differs from today's

``tests/test_docs_quoted.py`` runs the check in the quick suite. cog (cogapp) is in the test
extra of pyproject.toml.
"""

from __future__ import annotations

import contextlib
import difflib
import functools
import io
import itertools
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import textwrap
from collections.abc import Callable, Iterator
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: The files whose cog blocks this script fills.
COG_FILES = ("README.md", "docs/diagnosis.md")
WALK = "docs/walkthrough/session"
UNEXPLAINED = "docs/walkthrough/unexplained"
JUGGLEBOT = ROOT / "examples" / "jugglebot"


def _inputs(folder: str) -> list[str]:
    return [
        f"{folder}/measurements.csv",
        "--robot",
        f"{folder}/robot.json",
        "--instruments",
        f"{folder}/instruments.json",
    ]


@contextlib.contextmanager
def _in(folder: Path) -> Iterator[None]:
    here = Path.cwd()
    os.chdir(folder)
    try:
        yield
    finally:
        os.chdir(here)


@functools.cache
def hexcal(*args: str, where: str = "") -> str:
    """What ``hexcal ARGS`` prints on its standard output, run from ``where`` (default: the
    repository's root) in a process of its own, as a user runs it (an effect one run loads
    from a file must not be in the next)."""
    run = "import sys; from hexcal.app.cli import main; sys.exit(main(sys.argv[1:]))"
    done = subprocess.run(
        [sys.executable, "-c", run, *args],
        cwd=where or ROOT,
        capture_output=True,
        text=True,
        check=True,
        env=dict(os.environ, COLUMNS="100"),
    )
    return done.stdout


# -- the walkthrough ---------------------------------------------------------------------------
def walkthrough() -> str:
    """docs/walkthrough/diagnose.txt: the whole chain, --verbose."""
    return hexcal("diagnose", *_inputs(WALK), "--auto", "--verbose")


@functools.cache
def _unexplained() -> tuple[str, str, str]:
    """The unexplained walkthrough's two outputs and the effect file the first writes, run in
    a copy of its folder at the same relative path (the effect file is written there)."""
    with tempfile.TemporaryDirectory() as tmp:
        shutil.copytree(ROOT / UNEXPLAINED, Path(tmp) / UNEXPLAINED)
        effect = f"{UNEXPLAINED}/by_stroke.py"
        (Path(tmp) / effect).unlink()
        first = hexcal(
            "diagnose", *_inputs(UNEXPLAINED), "--auto", "--effect-file", effect, where=tmp
        )
        added = hexcal(
            "diagnose", *_inputs(UNEXPLAINED), "--effects", effect, "--add", "by_stroke", where=tmp
        )
        return first, added, (Path(tmp) / effect).read_text(encoding="utf-8")


#: The walkthrough's whole outputs, each file and what makes it.
TEXT_FILES: dict[str, Callable[[], str]] = {
    "docs/walkthrough/diagnose.txt": walkthrough,
    f"{UNEXPLAINED}/diagnose.txt": lambda: _unexplained()[0],
    f"{UNEXPLAINED}/diagnose_added.txt": lambda: _unexplained()[1],
}


def _chain_rows(text: str) -> list[list[str]]:
    """The rows of the before/after table (the error as effects are added), split in cells."""
    block = text.split("the error as effects are added", 1)[1].split("\n\n", 1)[0]
    return [re.split(r"\s{2,}", row.strip()) for row in block.splitlines()[2:]]


def walkthrough_table() -> None:
    """README's table: leg-length RMS and pose error, held-out, of the drawing, each model and
    the floor."""
    import cog

    rows = {r[0]: r for r in _chain_rows(walkthrough())}
    design = rows["design (drawing, all poses)"]
    m42, added = rows["Model 42"], rows["Model 42 + backlash"]
    floor = rows["pose floor (noise alone)"]
    drawing_mm = float(design[2]) / 1000
    cog.outl("| model | leg-length RMS, held-out | pose error (position, held-out) |")
    cog.outl("|---|---|---|")
    cog.outl(
        f"| the drawing (robot.json as designed) | {float(design[1]):.0f} µm | "
        f"{drawing_mm:.2f} mm, {float(design[4]):.2f}° |"
    )
    cog.outl(
        f"| Model 42 (the paper's geometry) | {float(m42[1]):.1f} µm | {float(m42[4]):.0f} µm |"
    )
    cog.outl(
        f"| Model 42 + backlash (named by `hexcal diagnose`) | {float(added[1]):.1f} µm | "
        f"{float(added[4]):.1f} µm |"
    )
    cog.outl(
        f"| noise floor (the instruments alone) | {float(m42[3]):.1f} µm | {float(floor[1]):.1f} µm |"
    )


def walkthrough_abridged() -> None:
    """docs/diagnosis.md's abridged first step: its statistics' opening, where, the top five
    candidates."""
    import cog

    step = walkthrough().split("\nhexcal diagnose: ", 1)[1].split("\nhexcal diagnose: ", 1)[0]
    lines = ("hexcal diagnose: " + step).splitlines()
    keep = lines[:3] + [x for x in lines if x.startswith("where:")]
    ranked = lines.index("missing effects, ranked:")
    keep += lines[ranked : ranked + 7] + ["", *(x for x in lines if x.startswith("verdict:"))]
    cog.outl("```")
    cog.outl("\n".join(keep))
    cog.outl("```")


# -- the Jugglebot ---------------------------------------------------------------------------
@functools.cache
def jugglebot() -> tuple[str, dict]:
    """The Jugglebot's log imported and diagnosed as its README says (``--auto --explore
    effects``): the text output (--verbose) and the JSON one."""
    with tempfile.TemporaryDirectory() as tmp:
        for name in ("108_calibration_poses.csv", "map.toml", "design-robot.json"):
            shutil.copy(JUGGLEBOT / name, tmp)
        log = ("108_calibration_poses.csv", "--map", "map.toml", "--out", "measurements.csv")
        hexcal("import", *log, where=tmp)
        args = ("diagnose", "measurements.csv", "--robot", "design-robot.json", "--auto")
        args += ("--explore", "effects")  # the chain carried through the explorer's leads
        return hexcal(*args, "--verbose", where=tmp), json.loads(hexcal(*args, "--json", where=tmp))


def _headline(text: str) -> str:
    from hexcal.app.plain import STATISTICS

    return text.split(f"\n\n{STATISTICS}\n", 1)[0]


def jugglebot_headline() -> None:
    """What the diagnosis opens with, as printed."""
    import cog

    cog.outl("```")
    cog.outl(_headline(jugglebot()[0]))
    cog.outl("```")


def jugglebot_chain() -> None:
    """The verdict chain: each step's verdict, what it added (a catalogue effect, or the
    explorer's lead through its file), the share of the excess a catalogue effect explains,
    and the fall of the held-out leg RMS."""
    import cog

    text, out = jugglebot()
    shares = dict(re.findall(r"^verdict: (\w+) — it explains (\d+) %", text, re.M))
    steps = out["steps"]
    parts, added = [], []
    for k, (step, after) in enumerate(itertools.pairwise(steps)):
        (effect,) = [e for e in after["effects"] if e not in step["effects"]]
        added.append(effect)
        fall = (
            f"held-out leg RMS {1000 * step['cv_rms_mm']:.0f} → {1000 * after['cv_rms_mm']:.0f} µm"
        )
        if step["verdict"] == "unexplained":
            what = f"`unexplained`, the explorer's lead `{effect}` added from its file ({fall})"
        elif step["verdict"] in shares:
            what = f"`{effect}` (explains {shares[effect]} % of the excess; {fall})"
        else:
            what = f"`{effect}` ({fall})"
        parts.append(("" if k == 0 else "then ") + what)
    files = [e for e in added if e.startswith("by_")]
    cog.outl(
        _bullet(
            f"**The verdict chain:** {', '.join(parts)}, then `{out['verdict']}`. No instrument "
            f"noise is known, so the floor is estimated (≈ {out['noise_floor_mm']:.2f} mm: the "
            "richest fit's residual, capped at the best held-out residual of the models tried) "
            "and every verdict is as firm as that estimate. `hexcal calibrate --add "
            f"{' '.join(added)}"
            + "".join(f" --effects effects/{e}.py" for e in files)
            + "` writes the same model as `diagnose --auto --explore effects --out`."
        )
    )


def _bullet(text: str) -> str:
    """A list item wrapped as the docs wrap them (100 columns, its lines indented)."""
    return textwrap.fill(
        text, 100, initial_indent="- ", subsequent_indent="  ", break_on_hyphens=False
    )


def _scales(out: dict) -> list[tuple[float, float]]:
    """Each leg's hand-measured mm per revolution and the fitted one (the gain applied)."""
    try:
        import tomllib
    except ModuleNotFoundError:  # Python 3.10
        import tomli as tomllib  # type: ignore[no-redef]

    hand = tomllib.loads((JUGGLEBOT / "map.toml").read_text())["readings"]["mm_per_unit"]
    gains = {p["name"]: p["value"] for p in out["parameters"] if p["name"].startswith("gain.")}
    return [(h, h * (1 + 1e-6 * gains[f"gain.g{k + 1}"])) for k, h in enumerate(hand)]


def _off(hand: float, fitted: float) -> float:
    return 100 * abs(fitted / hand - 1)


def jugglebot_scales() -> None:
    """The fitted mm per revolution against the builders' hand measure."""
    import cog

    _, out = jugglebot()
    scales = _scales(out)
    ci = max(p["ci95"] for p in out["parameters"] if p["name"].startswith("gain.") and "ci95" in p)
    worst = max(range(6), key=lambda k: _off(*scales[k]))
    others = [_off(*s) for k, s in enumerate(scales) if k != worst]
    hand = scales[worst][0]
    cog.outl(
        _bullet(
            "**The scales.** The fitted gains turn the hand-measured mm per revolution into "
            f"{', '.join(f'{f:.2f}' for _, f in scales)} (legs 1–6, ± {1e-6 * ci * hand:.2f}): "
            f"leg {worst + 1}'s hand measure ({hand:.2f}) is {_off(*scales[worst]):.1f} % off, "
            f"the others up to {max(others):.1f} %."
        )
    )


def jugglebot_worst() -> str:
    """ "6.4 %": how far the worst hand measure is off (README's sentence)."""
    return f"{max(_off(h, f) for h, f in _scales(jugglebot()[1])):.1f} %"


def jugglebot_steps() -> str:
    """ ", a step in the zero of legs 1 and 2 during the session": the legs whose zero the
    chain found stepping (empty when it named none)."""
    legs = [p["name"][len("zero_step.d") :] for p in jugglebot()[1]["parameters"]]
    legs = [k for k in legs if k.isdigit()]
    if not legs:
        return ""
    named = (
        "leg " + legs[0] if len(legs) == 1 else "legs " + ", ".join(legs[:-1]) + " and " + legs[-1]
    )
    return f", a step in the zero of {named} during the session"


# -- the whole ---------------------------------------------------------------------------------
def _cog(files: tuple[str, ...], check: bool) -> int:
    from cogapp import Cog

    args = ["cog", "-I", str(ROOT / "docs"), "--check" if check else "-r"]
    if check:
        args.append("--diff")
    with _in(ROOT):
        return Cog().main([*args, *files])


def check() -> list[str]:
    """What differs from today's output: a diff per quoted text file, cog's verdict on the
    blocks (empty when every quote is today's)."""
    found = []
    for name, make in TEXT_FILES.items():
        now, quoted = make(), (ROOT / name).read_text(encoding="utf-8")
        if now != quoted:
            found.append(
                "".join(
                    difflib.unified_diff(
                        quoted.splitlines(True), now.splitlines(True), name, "today"
                    )
                )
            )
    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(out):
        status = _cog(COG_FILES, check=True)
    if status:
        found.append(out.getvalue())
    return found


def report() -> None:
    """docs/walkthrough/report.html and its screenshots at 390, 768 and 1280 px (not checked:
    the page holds its date; tests/test_report_browser.py measures it). Headless Chromium lays
    a page out at least 500 px wide, so each width is a frame of that width in a host page."""
    page = ROOT / "docs" / "walkthrough" / "report.html"
    hexcal("diagnose", *_inputs(WALK), "--auto", "--report", str(page.relative_to(ROOT)))
    browser = next((b for b in ("chromium", "chromium-browser") if shutil.which(b)), None)
    if browser is None:
        print("no Chromium: the report's screenshots are left as they were", file=sys.stderr)
        return
    from PIL import Image  # matplotlib's

    with tempfile.TemporaryDirectory() as tmp:
        for width in (390, 768, 1280):
            host = Path(tmp) / f"host-{width}.html"
            host.write_text(
                f'<body style="margin:0"><iframe src="{page.as_uri()}" '
                f'style="border:0;width:{width}px;height:2200px"></iframe></body>'
            )
            shot = Path(tmp) / f"{width}.png"
            subprocess.run(
                [browser, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars",
                 "--allow-file-access-from-files", "--virtual-time-budget=5000",
                 f"--window-size={max(width, 520)},2200", f"--screenshot={shot}", host.as_uri()],
                check=True, capture_output=True, timeout=120,
            )  # fmt: skip
            Image.open(shot).crop((0, 0, width, 2200)).save(
                page.with_name(f"report-{width}.png"), optimize=True
            )


def write() -> None:
    """Every quote anew (the effect file the unexplained walkthrough writes, too), and the
    walkthrough's report with its screenshots."""
    for name, make in TEXT_FILES.items():
        (ROOT / name).write_text(make(), encoding="utf-8")
    (ROOT / UNEXPLAINED / "by_stroke.py").write_text(_unexplained()[2], encoding="utf-8")
    _cog(COG_FILES, check=False)
    report()


if __name__ == "__main__":
    if "--check" in sys.argv[1:]:
        drift = check()
        print("\n".join(drift) or "every quoted output is today's")
        sys.exit(1 if drift else 0)
    write()
