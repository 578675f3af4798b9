"""The fuzz harness: run `softforce` in-process, classify what a user would have seen.

A fuzz case passes when the command ends in one of two documented ways, within a time bound:
- "error": a non-zero exit with exactly one `error:` line on stderr, the last one (before it
  only `warning:` lines or a progress bar's last state), no traceback;
- "ok" or "warning": exit 0, no `error:` line; "warning" when a `warning:` line was printed.
Anything else (a Python exception escaping `main`, a traceback on stderr, a second error line,
a hang) fails the case. The fuzz suites (tests/test_fuzz_*.py) run a few hundred cases in
`make test`; SOFTFORCE_FUZZ_CASES=5000 (or `make fuzz`) runs more of each kind, and
SOFTFORCE_FUZZ_REPORT=FILE appends the count of each outcome per input kind to FILE (JSON lines).
"""

from __future__ import annotations

import io
import json
import os
import signal
import sys
import time
import traceback
import warnings
from collections import Counter
from contextlib import redirect_stderr, redirect_stdout
from dataclasses import dataclass
from pathlib import Path

import pytest

from softforce_cli.cli.main import main
from softforce_cli.errors import SoftforceError

TIME_LIMIT_S = 20.0  # generous on a loaded 2-core machine; a hang shows as far more


def fuzz_cases(default: int) -> int:
    """How many cases a fuzz test runs: `default`, scaled by SOFTFORCE_FUZZ_CASES (per kind)."""
    return int(os.environ.get("SOFTFORCE_FUZZ_CASES", default))


@dataclass(frozen=True)
class Outcome:
    args: tuple[str, ...]
    code: int | None  # None: an exception escaped main()
    stdout: str
    stderr: str
    escaped: str | None  # the traceback of an exception that escaped main()
    seconds: float


def run_cli(*args: str | Path) -> Outcome:
    """`softforce ARGS` in this process, as main() runs it; signal handlers restored after."""
    argv = ("softforce", *map(str, args))
    out, err = io.StringIO(), io.StringIO()
    saved_signals = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    saved_argv = sys.argv
    code, escaped = None, None
    started = time.perf_counter()
    try:
        sys.argv = list(argv)
        with warnings.catch_warnings(), redirect_stdout(out), redirect_stderr(err):
            try:
                main()
                code = 0
            except SystemExit as exit_:
                code = exit_.code if isinstance(exit_.code, int) else int(exit_.code is not None)
            except Exception:  # what a user would see as a traceback
                escaped = traceback.format_exc()
    finally:
        sys.argv = saved_argv
        for sig, handler in saved_signals.items():
            signal.signal(sig, handler)
    return Outcome(argv[1:], code, out.getvalue(), err.getvalue(), escaped,
                   time.perf_counter() - started)


def classify(outcome: Outcome) -> str:
    """'error', 'warning' or 'ok' (see the module docstring); AssertionError for anything else."""
    where = f"softforce {' '.join(outcome.args)}"
    assert outcome.escaped is None, f"{where} raised:\n{outcome.escaped}"
    assert "Traceback" not in outcome.stderr, f"{where}:\n{outcome.stderr}"
    assert outcome.seconds < TIME_LIMIT_S, f"{where} took {outcome.seconds:.1f} s"
    lines = [line for line in outcome.stderr.splitlines() if line.strip()]
    errors = [line for line in lines if line.startswith("error:")]
    warnings_ = [line for line in lines if line.startswith("warning:")]
    if outcome.code != 0:
        assert outcome.code == 1, f"{where} exited {outcome.code}:\n{outcome.stderr}"
        # progress lines (a bar's last state) and warnings may come before the error line
        assert len(errors) == 1 and lines[-1] == errors[0], (
            f"{where}: expected one error line, last:\n{outcome.stderr}")
        return "error"
    assert not errors, f"{where}:\n{outcome.stderr}"  # other lines: progress, "wrote ..."
    return "warning" if warnings_ else "ok"


def call_reader(function, *args) -> str:
    """A reader called directly: 'error' for a SoftforceError, 'warning' if it warned, 'ok'."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            function(*args)
        except SoftforceError as error:
            assert "\n" not in str(error), f"a multi-line error: {error}"
            return "error"
    return "warning" if caught else "ok"


def report(kind: str, counts: Counter) -> None:
    """Append this kind's outcome counts to SOFTFORCE_FUZZ_REPORT, if set (for the docs)."""
    target = os.environ.get("SOFTFORCE_FUZZ_REPORT")
    if target:
        with open(target, "a") as handle:
            handle.write(json.dumps({"kind": kind, "cases": sum(counts.values()),
                                     **dict(counts), "tracebacks": 0}) + "\n")


def test_harness_sees_a_clean_error(tmp_path):
    outcome = run_cli("record", "info", tmp_path / "missing.mcap")
    assert classify(outcome) == "error"
    assert "missing.mcap does not exist" in outcome.stderr


def test_harness_catches_an_escaping_exception(monkeypatch, tmp_path):
    """The harness must fail a case whose exception escapes: it would be a user's traceback."""
    from softforce_cli.cli import record_commands

    def broken(path):
        raise ZeroDivisionError("boom")

    monkeypatch.setattr(record_commands, "read_summary", broken)
    outcome = run_cli("record", "info", tmp_path / "x.mcap")
    assert outcome.code is None and "ZeroDivisionError" in outcome.escaped
    with pytest.raises(AssertionError, match="raised"):
        classify(outcome)


def test_harness_restores_signal_handlers():
    before = signal.getsignal(signal.SIGTERM)
    run_cli("--version")
    assert signal.getsignal(signal.SIGTERM) is before
