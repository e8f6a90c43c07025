"""How long each file of the bad-input regression corpus (tests/data/bad_inputs/) takes to be
refused by its reader: milliseconds each; a quadratic or runaway parse shows as seconds.

    python benchmarks/bad_input_refusal.py [--repeat 3]

Prints every file's best time over ``--repeat`` reads (ms), the slowest first, and exits 1 if
any file is read without an error. The messages are checked by tests/test_bad_inputs.py; the
time is measured here, not asserted in the suite (a shared machine's load would decide it).
"""

from __future__ import annotations

import argparse
import importlib.util
import sys
import time
from pathlib import Path

TESTS = Path(__file__).resolve().parents[1] / "tests"


def _corpus_module():
    """tests/test_bad_inputs.py: its readers and cases, one list for the test and for this."""
    spec = importlib.util.spec_from_file_location("bad_inputs", TESTS / "test_bad_inputs.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args(argv)
    corpus = _corpus_module()
    times, accepted = [], []
    for name in sorted(corpus.CASES):
        read, error = corpus.READERS[name.split("-")[0]]
        best = float("inf")
        for _ in range(args.repeat):
            start = time.perf_counter()
            try:
                read(corpus.BAD / name)
            except error:
                pass
            else:
                accepted.append(name)
            best = min(best, time.perf_counter() - start)
        times.append((best, name))
    for best, name in sorted(times, reverse=True):
        print(f"{1000 * best:9.2f} ms  {name}")
    if accepted:
        print("read without an error:", ", ".join(sorted(set(accepted))))
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
