"""The dependency arrows point one way (docs/architecture.md, issue 14).

* No module of ``fohssv_sim`` imports ``fohssv_controller``: the controller contract and the
  plugin registry are in the core (:mod:`fohssv_sim.control`); the core finds the built-in
  laws through entry points.
* No node module (``*_node.py``) imports another node module: shared node plumbing is in
  :mod:`fohssv_sim.ros.nodekit`.
* No core module imports the CLI (``fohssv_sim.cli``), and the core (everything outside
  ``fohssv_sim.ros``) imports no rclpy, checked by importing every core module in a process
  where rclpy cannot be imported.
* Nothing outside the ROS layers (``fohssv_sim.ros``, ``fohssv_controller.ros``) imports from
  ``fohssv_sim.ros``: what the core and the ROS side share lives in the core.
* No import circle among the modules of both packages.

Read from the source with ``ast`` (every import statement, function-local ones included).
"""

from __future__ import annotations

import ast
import functools
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SIM = ROOT / 'src' / 'fohssv_sim' / 'fohssv_sim'
CONTROLLER = ROOT / 'src' / 'fohssv_controller' / 'fohssv_controller'


def _module_name(path: Path, package_dir: Path) -> str:
    rel = path.relative_to(package_dir.parent).with_suffix('')
    parts = list(rel.parts)
    if parts[-1] == '__init__':
        parts.pop()
    return '.'.join(parts)


@functools.cache
def _imports(path: Path, package_dir: Path) -> frozenset[str]:
    """Absolute names of every module ``path`` imports (relative imports resolved); each file
    is parsed once per test process (the tests here read the same tree)."""
    name = _module_name(path, package_dir)
    package = name if path.name == '__init__.py' else name.rpartition('.')[0]
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split('.')
                base = base[:len(base) - node.level + 1]
                mod = '.'.join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ''
            found.add(mod)
            found.update(f'{mod}.{a.name}' for a in node.names)
    return frozenset(found)


def _modules(package_dir: Path) -> list[Path]:
    return sorted(p for p in package_dir.rglob('*.py') if '__pycache__' not in p.parts)


def test_no_core_module_imports_the_controller_package():
    bad = {str(p.relative_to(ROOT)): sorted(i for i in _imports(p, SIM)
                                            if i.split('.')[0] == 'fohssv_controller')
           for p in _modules(SIM)}
    assert {k: v for k, v in bad.items() if v} == {}


def test_no_node_module_imports_another_node_module():
    nodes = {p: d for d in (SIM, CONTROLLER) for p in _modules(d) if p.stem.endswith('_node')}
    names = {_module_name(p, d) for p, d in nodes.items()}
    assert {'fohssv_sim.ros.plant_node', 'fohssv_controller.ros.controller_node'} <= names
    bad = {}
    for p, d in nodes.items():
        own = _module_name(p, d)
        other = sorted(i for i in _imports(p, d) if i != own and (
            i in names or i.rpartition('.')[0] in names - {own}))
        if other:
            bad[str(p.relative_to(ROOT))] = other
    assert bad == {}


def _outside_ros(path: Path, package_dir: Path) -> bool:
    return path.relative_to(package_dir).parts[0] != 'ros'


def test_nothing_outside_the_ros_layers_imports_fohssv_sim_ros():
    bad = {}
    for d in (SIM, CONTROLLER):
        for p in _modules(d):
            if not _outside_ros(p, d):
                continue
            hits = sorted(i for i in _imports(p, d) if i == 'fohssv_sim.ros'
                          or i.startswith('fohssv_sim.ros.'))
            if hits:
                bad[str(p.relative_to(ROOT))] = hits
    assert bad == {}


def _import_graph() -> dict[str, set[str]]:
    """Module -> the modules of both packages it imports (a name resolved to the nearest
    module that contains it; a module's own enclosing packages left out, as Python imports
    them before the module anyway)."""
    files = {_module_name(p, d): (p, d) for d in (SIM, CONTROLLER) for p in _modules(d)}
    graph = {}
    for name, (p, d) in files.items():
        graph[name] = set()
        for i in _imports(p, d):
            while i and i not in files:
                i = i.rpartition('.')[0]
            if i and i != name and not name.startswith(i + '.'):
                graph[name].add(i)
    return graph


def _reach(graph: dict[str, set[str]], start: str) -> set[str]:
    seen, todo = set(), list(graph[start])
    while todo:
        m = todo.pop()
        if m not in seen:
            seen.add(m)
            todo.extend(graph[m])
    return seen


def import_circles(graph: dict[str, set[str]]) -> set[frozenset[str]]:
    """The sets of modules that import each other, directly or through others."""
    reach = {m: _reach(graph, m) for m in graph}
    return {frozenset({m} | {n for n in reach[m] if m in reach[n]})
            for m in graph if m in reach[m]}


def test_the_circle_finder_finds_a_circle_and_only_it():
    graph = {'a': {'b'}, 'b': {'c'}, 'c': {'a', 'd'}, 'd': set(), 'e': {'d', 'e'}}
    assert import_circles(graph) == {frozenset('abc'), frozenset('e')}


def test_no_import_circle():
    graph = _import_graph()
    assert 'fohssv_sim.analysis.tune' in graph['fohssv_sim.cli.tune']   # lazy imports count
    assert import_circles(graph) == set()


def test_only_the_cli_imports_the_cli():
    bad = {}
    for p in _modules(SIM):
        if 'cli' in p.relative_to(SIM).parts[:1]:
            continue
        hits = sorted(i for i in _imports(p, SIM) if i == 'fohssv_sim.cli'
                      or i.startswith('fohssv_sim.cli.'))
        if hits:
            bad[str(p.relative_to(ROOT))] = hits
    assert bad == {}


_BLOCK_RCLPY = '''
import importlib, sys

class Block:
    def find_spec(self, name, path=None, target=None):
        if name == 'rclpy' or name.startswith('rclpy.'):
            raise ImportError(f'rclpy is blocked: the core must not import {name}')
        return None

sys.meta_path.insert(0, Block())
failed = []
for name in sys.argv[1:]:
    try:
        importlib.import_module(name)
    except Exception as exc:
        failed.append(f'{name}: {type(exc).__name__}: {exc}')
print('\\n'.join(failed))
sys.exit(1 if failed else 0)
'''


def test_every_core_module_imports_without_rclpy():
    names = sorted(_module_name(p, SIM) for p in _modules(SIM)
                   if p.relative_to(SIM).parts[0] != 'ros' and p.name != '__main__.py')
    assert 'fohssv_sim.control' in names and 'fohssv_sim.cli' in names
    env = {k: v for k, v in os.environ.items()}
    out = subprocess.run([sys.executable, '-c', _BLOCK_RCLPY, *names], env=env,
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stdout + out.stderr


def test_nodes_that_simulate_nothing_start_without_numba():
    """The controller, recorder, player and viewer nodes import neither the compiled kernels nor
    numba (about 0.3 s of CPU at every start): only the plant simulates."""
    modules = ['fohssv_controller.ros.controller_node', 'fohssv_sim.ros.recorder_node',
               'fohssv_sim.ros.player_node', 'fohssv_sim.ros.viewer_node']
    code = ('import importlib, sys\n'
            f'for name in {modules!r}:\n'
            '    importlib.import_module(name)\n'
            "print(sorted(m for m in sys.modules if m.split('.')[0] == 'numba'\n"
            "             or m == 'fohssv_sim.kernels'))\n")
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == '[]', out.stdout


_CLI_IMPORTS = '''
import contextlib, io, json, sys
from fohssv_sim.cli import main
out = io.StringIO()
with contextlib.redirect_stdout(out):
    try:
        main(sys.argv[1:])
    except SystemExit:
        pass
heavy = ('matplotlib', 'dask', 'distributed', 'numba', 'scipy')
print(json.dumps({'help': out.getvalue(),
                  'heavy': sorted(m for m in sys.modules if m.split('.')[0] in heavy
                                  and m.count('.') < 2),
                  'commands': sorted(m for m in sys.modules if m.startswith('fohssv_sim.cli.')
                                     and m != 'fohssv_sim.cli.common')}))
'''


def _cli_imports(*argv: str) -> dict:
    import json

    out = subprocess.run([sys.executable, '-c', _CLI_IMPORTS, *argv], capture_output=True,
                         text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout)


def test_cli_imports_only_the_subcommand_that_runs():
    """``fohssv --help`` lists every subcommand without importing one of their modules (nor
    matplotlib, Dask, numba or scipy: about 0.8 CPU s at each start); ``fohssv NAME`` imports
    the module of NAME only. The listing is the one of the parser with every module
    imported."""
    from fohssv_sim.cli import COMMANDS, build_parser

    top = _cli_imports('--help')
    assert top['heavy'] == [] and top['commands'] == [], top
    assert top['help'] == build_parser().format_help()
    for name in COMMANDS:
        assert f'    {name} ' in top['help'], name
    fit = _cli_imports('fit', '--help')
    # fit and the module it takes its Dask options from
    assert fit['commands'] == ['fohssv_sim.cli.fit', 'fohssv_sim.cli.sweep'], fit['commands']
    assert 'usage: fohssv fit' in fit['help'] and '--reference' in fit['help']
    assert fit['heavy'] == [], fit['heavy']      # its parser alone: no figures, no solver
    check = _cli_imports('check', '--help')
    assert check['commands'] == ['fohssv_sim.cli.plot'], check['commands']
