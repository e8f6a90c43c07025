"""The data flow, checked on the imports: a module imports only from its own stage or an
earlier one, and no production module imports the simulator or the mock hardware.

    io → model → effects → estimate → diagnosis → acquire → procedure → (sim) → app

Each stage is one subpackage of ``hexcal`` (``hexcal.io``, ``hexcal.model``...; the drivers,
the mock hardware and the procedure files keep their top-level folders as the design card asks).
``sim`` (the simulator, simulated sessions and robots, the study, mock hardware) sits beside
the flow: it may use every production stage, and only the application layer (the CLI, the
text UI, the workflow under them) may use it — for ``simulate``, ``demo``, ``study`` and
``--mock``. Imports are read from the source with ``ast`` (lazy imports inside functions
included)."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SOURCES = {
    "src/hexcal": "hexcal",
    "drivers": "hexcal.drivers",
    "mock_hw": "hexcal.mock_hw",
    "procedures": "hexcal.procedures",
}
#: Stages in flow order: module name prefixes (the longest prefix decides). Each stage is one
#: subpackage (the drivers and the mock hardware keep their top-level folders, design card).
STAGES = {
    "base": [
        "hexcal",  # the package's own __init__: version and the lazy public API (see below)
        "hexcal.errors",
        "hexcal.vocabulary",
    ],
    "io": ["hexcal.io"],
    "model": ["hexcal.model"],
    "effects": ["hexcal.effects"],
    "estimate": ["hexcal.estimate"],
    "diagnosis": ["hexcal.diagnosis"],
    "acquire": ["hexcal.acquire", "hexcal.drivers"],
    "procedure": ["hexcal.procedure", "hexcal.procedures"],
    "sim": ["hexcal.sim", "hexcal.mock_hw"],
    "app": ["hexcal.app", "hexcal.tui"],
}
ORDER = list(STAGES)
PRODUCTION = ORDER[: ORDER.index("sim")]
#: Imports that run against the flow, each with its reason; the test fails when one is added,
#: and when one listed here is gone (so the list only shrinks).
KNOWN: dict[tuple[str, str], str] = {}
#: The package __init__ names the public API by module path and imports it lazily: its
#: TYPE_CHECKING imports are for the type checker, not a dependency of the model stage.
LAZY_API = "hexcal"


def stage_of(module: str) -> str | None:
    best: tuple[int, str] | None = None
    for name, prefixes in STAGES.items():
        for p in prefixes:
            if (module == p or module.startswith(p + ".")) and (best is None or len(p) > best[0]):
                best = (len(p), name)
    return None if best is None else best[1]


def modules():
    for root, package in SOURCES.items():
        for path in sorted((ROOT / root).rglob("*.py")):
            parts = path.relative_to(ROOT / root).with_suffix("").parts
            if parts[-1] == "__init__":
                parts = parts[:-1]
            yield ".".join((package, *parts)), path


def imports(path: Path) -> set[str]:
    out = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            out.add(node.module)
        elif isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
    return {m for m in out if m == "hexcal" or m.startswith("hexcal.")}


def against_the_flow() -> dict[tuple[str, str], str]:
    found = {}
    for module, path in modules():
        here = stage_of(module)
        assert here is not None, f"{module} belongs to no stage: add it to STAGES"
        if here == "app" or module == LAZY_API:
            continue
        for target in imports(path):
            there = stage_of(target)
            assert there is not None, f"{module} imports {target}, which belongs to no stage"
            if here in PRODUCTION and there == "sim":
                found[(module, target)] = f"{here} → sim"
            elif ORDER.index(there) > ORDER.index(here) and not (
                here == "sim" and there in PRODUCTION
            ):
                found[(module, target.split(".")[0] + "." + target.split(".")[1])] = (
                    f"{here} → {there}"
                )
    return found


#: Import cycles between modules (lazy imports included), each a sorted tuple of its modules;
#: the test fails when a new one appears and when one listed here is gone (the list only
#: shrinks). Two modules that import each other cannot be read, tested or split apart alone.
KNOWN_CYCLES: set[tuple[str, ...]] = {
    ("hexcal", "hexcal.estimate.model_file"),  # the lazy public API (LAZY_API) names it
}


def module_imports(path: Path, known: set[str]) -> set[str]:
    """The modules of ``known`` that ``path`` imports: ``from hexcal.io import measurements_csv``
    counts as importing ``hexcal.io.measurements_csv`` (a package's attribute that is a
    module), and an imported name resolves to the longest known module that holds it."""
    out = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            for alias in node.names:
                full = f"{node.module}.{alias.name}"
                out.add(full if full in known else node.module)
        elif isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
    resolved = set()
    for target in out:
        while target and target not in known:
            target = target.rpartition(".")[0]
        if target:
            resolved.add(target)
    return resolved


def import_cycles() -> set[tuple[str, ...]]:
    """The strongly connected groups of two or more modules in the import graph (Tarjan)."""
    paths = dict(modules())
    known = set(paths)
    graph = {m: sorted(module_imports(p, known) - {m}) for m, p in paths.items()}
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    cycles: set[tuple[str, ...]] = set()

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            group = []
            while True:
                w = stack.pop()
                group.append(w)
                if w == v:
                    break
            if len(group) > 1:
                cycles.add(tuple(sorted(group)))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return cycles


def test_no_new_import_cycle():
    """No two modules import each other, directly or round a ring (``hexcal.io`` has none:
    the measurement table's reader imports the table, never the other way round)."""
    found = import_cycles()
    new = found - KNOWN_CYCLES
    assert not new, f"import cycles: {sorted(new)}"
    gone = KNOWN_CYCLES - found
    assert not gone, f"fixed, so take them off KNOWN_CYCLES: {sorted(gone)}"
    assert not [c for c in found if any(m.startswith("hexcal.io") for m in c)]


def test_every_module_belongs_to_a_stage_and_imports_run_down_the_flow():
    found = against_the_flow()
    new = {k: v for k, v in found.items() if k not in KNOWN}
    assert not new, "imports against the data flow (or into sim): " + "; ".join(
        f"{a} imports {b} ({why})" for (a, b), why in sorted(new.items())
    )
    gone = set(KNOWN) - set(found)
    assert not gone, f"fixed, so take them off KNOWN: {sorted(gone)}"


def test_no_production_module_imports_the_simulator_or_mock_hardware():
    for module, path in modules():
        if stage_of(module) in PRODUCTION and module != LAZY_API:
            bad = {t for t in imports(path) if stage_of(t) == "sim"}
            assert not bad, f"{module} imports {sorted(bad)}"


def test_one_exception_hierarchy():
    """Every exception class hexcal defines (outside tests and the mocks) derives from
    HexcalError, through InputError, DeviceError or RefusedError where it is one of those."""
    import importlib
    import inspect

    from hexcal.errors import HexcalError

    loose = []
    for module, _ in modules():
        if stage_of(module) == "sim" or module.endswith("__main__"):
            continue
        mod = importlib.import_module(module)
        for name, obj in vars(mod).items():
            if (
                inspect.isclass(obj)
                and issubclass(obj, BaseException)
                and obj.__module__ == module
                and not name.startswith("_")
                and not issubclass(obj, HexcalError)
            ):
                loose.append(f"{module}.{name}")
    assert not loose, loose


def test_the_folders_are_the_stages():
    """Nothing lies loose beside the stage packages: a new module goes into its stage's folder."""
    top = ROOT / "src" / "hexcal"
    base = ("__init__.py", "errors.py", "vocabulary.py")
    loose = sorted(p.name for p in top.glob("*.py") if p.name not in base)
    assert loose == []
    packages = sorted(p.name for p in top.iterdir() if (p / "__init__.py").exists())
    expected = sorted(s.split(".")[1] for prefixes in STAGES.values() for s in prefixes if "." in s)
    not_folders = {"errors", "vocabulary", "drivers", "mock_hw", "procedures"}
    assert packages == sorted(set(expected) - not_folders)
