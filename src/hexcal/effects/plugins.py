"""Effects from outside hexcal: installed packages and Python files the user names.

- **Installed packages** declare their effects in the entry-point group ``hexcal.effects``, one
  entry point per effect, named as the effect and pointing at its class::

      [project.entry-points."hexcal.effects"]
      legsag = "hexcal_legsag:LegSag"

  :func:`load_installed` imports them when :mod:`hexcal.effects` is first imported: installing
  the package is the user's act. A package that fails to import, or whose effect breaks the API,
  is left out and said (:func:`failures`); hexcal goes on with the rest.
- **A file** named with ``--effects FILE.py`` (or in the rig file's ``effects`` list for the text
  UI) runs once per process, as the user's own code (:func:`load_file`). Every effect it
  registers comes from that file, recorded with the SHA-256 of the bytes that ran.

Nothing in a data file is ever executed: a calibrated.json only *names* where each of its effects
came from, and a model whose effect is not loaded is refused with what to install or pass.
"""

from __future__ import annotations

import hashlib
import sys
import traceback
import types
from collections.abc import Iterable
from importlib.metadata import EntryPoint, entry_points
from pathlib import Path

from hexcal.effects.base import (
    CATALOGUE,
    FAILED_PACKAGES,
    Effect,
    EffectError,
    EffectSource,
    loading_from,
    register,
)

#: The entry-point group installed packages declare their effects in.
ENTRY_POINT_GROUP = "hexcal.effects"
#: Largest effect file hexcal runs, bytes (an effect is a page of code, not a data set).
MAX_FILE_BYTES = 1 << 20

#: Entry point name (the effect's name) → why its package failed to load (kept in
#: :mod:`hexcal.effects.base`, whose :func:`~hexcal.effects.base.get_effect` says it).
_failed = FAILED_PACKAGES
#: SHA-256 of a file already run → the effects it registered.
_files: dict[str, list[str]] = {}
_installed_loaded = False


def load_installed() -> list[str]:
    """Load the effects of every installed package's ``hexcal.effects`` entry points, once per
    process; returns the names registered now. Failures are kept for :func:`failures`."""
    global _installed_loaded
    if _installed_loaded:
        return []
    _installed_loaded = True
    names: list[str] = []
    for ep in sorted(entry_points(group=ENTRY_POINT_GROUP), key=lambda e: e.name):
        names += _load_entry_point(ep)
    return names


def _package_source(ep: EntryPoint) -> EffectSource:
    dist = ep.dist
    name = (dist.metadata["Name"] if dist is not None else None) or ep.module
    version = dist.version if dist is not None else ""
    return EffectSource(
        "package", package=name, version=version, entry_point=f"{ep.name} = {ep.value}"
    )


def _load_entry_point(ep: EntryPoint) -> list[str]:
    source = _package_source(ep)
    before = set(CATALOGUE)
    try:
        with loading_from(source):
            obj = ep.load()
            if (
                isinstance(obj, type)
                and issubclass(obj, Effect)
                and not any(type(e) is obj for e in CATALOGUE.values())
            ):
                register(obj)  # the package forgot @register: its entry point names the class
        new = [n for n in CATALOGUE if n not in before]
        if not new and not any(type(e) is obj for e in CATALOGUE.values()):
            raise EffectError(
                f"entry point {ep.value} is no effect: name a subclass of hexcal.effects.Effect"
            )
    except Exception as exc:
        for n in set(CATALOGUE) - before:
            del CATALOGUE[n]
        why = str(exc) if isinstance(exc, EffectError) else f"{type(exc).__name__}: {exc}"
        _failed[ep.name] = f"effect {ep.name!r} of {source.text()} ({ep.value}): {why}"
        return []
    return new


def failures() -> list[str]:
    """One line per installed effect that failed to load, saying what to fix."""
    return [f"{text}; it is left out — fix or uninstall the package" for text in _failed.values()]


def failure_of(name: str) -> str | None:
    """Why the installed effect ``name`` failed to load (None when it did not fail)."""
    return _failed.get(name)


def load_file(path: str | Path) -> list[str]:
    """Run the Python file ``path`` (the user's explicit act) and register the effects it
    defines; returns their names. The same content runs once per process (a second call returns
    the same names). Refused, naming the file and line: not readable, not ``.py``, too large,
    not valid Python, failing when run, or registering no effect."""
    path = Path(path)
    if path.suffix != ".py":
        raise EffectError(f"{path}: an effect file is Python source ending in .py")
    try:
        with path.open("rb") as fh:
            raw = fh.read(MAX_FILE_BYTES + 1)
    except OSError as exc:
        raise EffectError(f"{path}: cannot read the effect file ({exc.strerror or exc})") from None
    if len(raw) > MAX_FILE_BYTES:
        raise EffectError(f"{path}: larger than {MAX_FILE_BYTES} bytes; an effect file is code")
    sha = hashlib.sha256(raw).hexdigest()
    if sha in _files and all(n in CATALOGUE for n in _files[sha]):
        return list(_files[sha])
    try:
        code = compile(raw, str(path), "exec", dont_inherit=True)
    except (SyntaxError, ValueError) as exc:
        line = f", line {exc.lineno}" if isinstance(exc, SyntaxError) and exc.lineno else ""
        msg = exc.msg if isinstance(exc, SyntaxError) else str(exc)
        raise EffectError(f"{path}{line}: not valid Python ({msg})") from None
    module = types.ModuleType(f"hexcal_effects_file_{sha[:16]}")
    module.__file__ = str(path)
    sys.modules[module.__name__] = module  # dataclasses and pickling-free typing look it up
    before = set(CATALOGUE)
    try:
        with loading_from(EffectSource("file", file=path.name, sha256=sha)):
            exec(code, module.__dict__)  # the user named this file to run: the point of --effects
    except Exception as exc:
        _forget(before, module.__name__)
        if isinstance(exc, EffectError):
            raise EffectError(f"{path}: {exc}") from None
        raise EffectError(
            f"{path}{_line_in(exc, path)}: running it failed: {type(exc).__name__}: {exc}"
        ) from None
    new = [n for n in CATALOGUE if n not in before]
    if not new:
        _forget(before, module.__name__)
        raise EffectError(
            f"{path}: registers no effect: decorate a subclass of hexcal.effects.Effect with "
            "@register (docs/effects.md)"
        )
    _files[sha] = new
    return list(new)


def load_files(paths: Iterable[str | Path]) -> list[str]:
    """:func:`load_file` of each path in turn; the names registered."""
    names: list[str] = []
    for p in paths:
        names += load_file(p)
    return names


def _forget(before: set[str], module: str) -> None:
    for n in set(CATALOGUE) - before:
        del CATALOGUE[n]
    sys.modules.pop(module, None)


def _line_in(exc: BaseException, path: Path) -> str:
    """``, line N``: the deepest line of ``path`` in the exception's traceback."""
    lines = [f.lineno for f in traceback.extract_tb(exc.__traceback__) if f.filename == str(path)]
    return f", line {lines[-1]}" if lines else ""
