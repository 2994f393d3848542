"""Run ``pymcap-cli doctor`` (pinned test dependency) on an MCAP file and parse its findings."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

DOCTOR = Path(sys.executable).parent / 'pymcap-cli'


def doctor(mcap: Path) -> tuple[dict, list[dict]]:
    """(summary, findings) of ``pymcap-cli doctor --format jsonl mcap``."""
    out = subprocess.run([str(DOCTOR), 'doctor', '--format', 'jsonl', str(mcap)],
                         capture_output=True, text=True, timeout=120)
    lines = [json.loads(line) for line in out.stdout.splitlines() if line.startswith('{')]
    summary = [r for r in lines if r.get('type') == 'summary']
    assert len(summary) == 1, f'doctor exit {out.returncode}: {out.stdout}{out.stderr}'
    return summary[0], [r for r in lines if r.get('type') == 'finding']


def assert_doctor_clean(mcap: Path) -> dict:
    """No error and no warning (info findings, e.g. NO_COMPRESSION, are allowed)."""
    summary, findings = doctor(mcap)
    bad = [f"{f['severity']} {f['code']}: {f['message']}" for f in findings
           if f['severity'] in ('error', 'warning')]
    assert not bad and summary['errors'] == 0 and summary['warnings'] == 0, (mcap, bad)
    return summary
