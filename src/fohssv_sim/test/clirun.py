"""The analysis CLI run in the test process (no new interpreter importing numpy, numba, scipy
and matplotlib for each case); the installed script is run by the tests whose subject it is."""

from __future__ import annotations

__test__ = False  # nothing to collect


def fohssv(capfd, *args) -> tuple[int, str, str]:
    """``fohssv ARGS`` through :func:`fohssv_sim.cli.main`: (exit code, stdout, stderr), the
    output captured by pytest's ``capfd`` from this call only."""
    from fohssv_sim.cli import main

    capfd.readouterr()
    try:
        code = main([str(a) for a in args])
    except SystemExit as e:      # argparse's own exits (usage errors)
        code = e.code
    out = capfd.readouterr()
    return code, out.out, out.err
