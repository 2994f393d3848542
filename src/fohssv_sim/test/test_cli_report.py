"""`fohssv report --quick`: the whole pipeline on a tiny grid (not converged results).

Run in-process through :func:`fohssv_sim.cli.main` on the session's Dask cluster of threads
(``--scheduler``): the installed script and its own local cluster are run by
test_cli_bad_input, test_cli_plot and test_sweep; a new interpreter and a worker process
would cost more than the tiny report itself."""

import json
import math

import numpy as np
from PIL import Image

from fohssv_sim.cli import main

from test_equilibria import analytic_jacobian, reduced_equilibrium

QUICK = 'quick (not converged)'


def test_quick_report_has_every_claim_with_independent_numbers(tmp_path, dask_cluster, capfd):
    capfd.readouterr()
    code = main(['report', '--quick', '--out', str(tmp_path), '--scheduler',
                 dask_cluster.scheduler_address])
    out = capfd.readouterr()
    assert code == 0, out.err
    rows = json.loads((tmp_path / 'claims.json').read_text())
    claims = [r['claim'] for r in rows]
    for fig in ('Fig. 3/4', 'Fig. 5', 'Fig. 6', 'Fig. 7', 'Fig. 8', 'Fig. 9', 'Fig. 10'):
        assert any(c.startswith(fig) for c in claims), fig
    assert all(r['verdict'] and r['evidence'] for r in rows)
    # Fig. 5 row: alpha_c at V = 75 from the eigenvalue formula (smooth vs exact planing
    # agree to 1e-4 at the equilibrium, which sits past the contact point)
    c, x = reduced_equilibrium(75.0)
    lam = np.linalg.eigvals(analytic_jacobian(c, x))
    alpha_c = min(abs(math.atan2(v.imag, v.real)) for v in lam) / (math.pi / 2)
    fig5 = next(r for r in rows if r['claim'].startswith('Fig. 5'))
    assert f'alpha_c = {alpha_c:.4f}' in fig5['model']
    assert fig5['verdict'] == f"{QUICK}: {'holds' if alpha_c > 0.85 else 'does not hold'}"
    c, x = reduced_equilibrium(84.5)
    fig7 = next(r for r in rows if r['claim'].startswith('Fig. 7: equilibrium'))
    assert f'({x[0]:.4f}, {x[1]:.4f}, {x[2]:.4f}' in fig7['model']
    report = (tmp_path / 'report.md').read_text()
    assert '| claim | model | evidence | verdict |' in report
    for fig in ('fig3_time_responses', 'fig6_orbit_alpha', 'fig8_orbit_V', 'fig10_alpha_V'):
        assert (tmp_path / f'{fig}.png').stat().st_size > 10_000
        assert f'({fig}.png)' in report
    side = json.loads((tmp_path / 'fig6_alpha_V84.5' / 'sweep.json').read_text())
    assert side['step'] == 2e-5 and side['solver'] == 'soe'

    # quick: labelled in report.md, in every claims.json row and on every figure
    assert report.startswith(f'# fohssv reproduction report: {QUICK}\n')
    assert f'**{QUICK}**' in report
    assert all(r['run'] == QUICK and r['verdict'].startswith(f'{QUICK}: ') for r in rows)
    pngs = sorted(tmp_path.glob('*.png'))
    assert len(pngs) == 7
    for png in pngs:
        with Image.open(png) as im:
            assert im.text.get('Title', '').startswith(QUICK + '\n'), png.name
    # sweep progress per point on a pipe: lines, no carriage returns
    assert '\r' not in out.err and 'fig6_alpha_V84.5: points 2/2' in out.err
