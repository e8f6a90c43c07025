"""The benchmarks run as the ``hexcal`` command does: its BLAS thread setting, applied by the
CLI's own function before numpy is loaded."""

from __future__ import annotations

from hexcal.app.cli import single_thread_blas

if not single_thread_blas():  # pragma: no cover - a plugin loaded numpy before this file
    raise RuntimeError(
        "numpy was imported before benchmarks/conftest.py: the benchmarks would not run with "
        "the CLI's BLAS thread setting"
    )
