"""Run ``pymcap-cli doctor`` (pinned test dependency) on an MCAP file and parse its findings.

The doctor command's function runs in this process (``pymcap_cli.cmd.doctor_cmd.doctor``,
what ``pymcap-cli doctor`` calls, writing its JSONL to stdout): the command-line tool's start
(cyclopts, rich and every other command's imports) cost more than the check of a test bag.
"""

from __future__ import annotations

import contextlib
import io
import json
from pathlib import Path


def doctor(mcap: Path) -> tuple[dict, list[dict]]:
    """(summary, findings) of ``pymcap-cli doctor --format jsonl mcap``."""
    from pymcap_cli.cmd.doctor_cmd import doctor as doctor_command

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = doctor_command(str(mcap), format='jsonl')
    lines = [json.loads(line) for line in out.getvalue().splitlines() if line.startswith('{')]
    summary = [r for r in lines if r.get('type') == 'summary']
    assert len(summary) == 1, f'doctor exit {code}: {out.getvalue()}{err.getvalue()}'
    return summary[0], [r for r in lines if r.get('type') == 'finding']


def assert_doctor_clean(mcap: Path) -> dict:
    """No error and no warning (info findings, e.g. NO_COMPRESSION, are allowed)."""
    summary, findings = doctor(mcap)
    bad = [f"{f['severity']} {f['code']}: {f['message']}" for f in findings
           if f['severity'] in ('error', 'warning')]
    assert not bad and summary['errors'] == 0 and summary['warnings'] == 0, (mcap, bad)
    return summary
