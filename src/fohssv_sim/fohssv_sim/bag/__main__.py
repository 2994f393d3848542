"""``python -m fohssv_sim.bag info|check|repair BAG``.

Exit codes: 0 success; 1 the path is not a (sound) bag, with a one-line ``error:`` on stderr;
2 bad usage. Never a traceback for a bad bag.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence

from .check import main_check
from .loader import BagError, load_run
from .repair import main_repair

USAGE = '''usage: python -m fohssv_sim.bag COMMAND BAG
  info BAG     what the run holds: topics, counts, times, run metadata (reads cut bags too)
  check BAG    structural check (CRCs, indexes, summary, metadata.yaml); exit 1 on a problem
  repair BAG   rebuild index, summary and metadata.yaml of a bag whose recorder was killed'''


def main_info(argv: Sequence[str]) -> int:
    """``info BAG``: summary of the run."""
    if len(argv) != 1:
        print('usage: python -m fohssv_sim.bag info BAG', file=sys.stderr)
        return 2
    try:
        run = load_run(argv[0])
    except BagError as exc:
        print(f'error: {exc}', file=sys.stderr)
        return 1
    print(f'bag:      {run.path}')
    print(f"state:    {len(run.t)} samples, t = {run.t[0] if len(run.t) else float('nan'):.9g} "
          f"... {run.t[-1] if len(run.t) else float('nan'):.9g} s")
    for topic, n in run.topics.items():
        print(f'topic:    {topic}: {n} messages')
    for key in sorted(run.metadata):
        value = run.metadata[key]
        text = value if isinstance(value, str) else repr(value)
        print(f'metadata: {key} = {text if len(text) <= 200 else text[:197] + "..."}')
    if run.truncated:
        print(f'WARNING: truncated bag: {run.recovery}')
        print(f'         repair it with: python -m fohssv_sim.bag repair {argv[0]}')
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    args = list(sys.argv[1:] if argv is None else argv)
    commands = {'info': main_info, 'check': main_check, 'repair': main_repair}
    if not args or args[0] not in commands:
        print(USAGE, file=sys.stderr)
        return 2
    try:
        return commands[args[0]](args[1:])
    except BagError as exc:
        print(f'error: {exc}', file=sys.stderr)
    except OSError as exc:
        print(f'error: {exc}', file=sys.stderr)
    except Exception as exc:  # noqa: BLE001 - a bad bag must never end in a traceback
        print(f'error: {" ".join(args[1:])}: unexpected {type(exc).__name__}: {exc}',
              file=sys.stderr)
    return 1


if __name__ == '__main__':
    sys.exit(main())
