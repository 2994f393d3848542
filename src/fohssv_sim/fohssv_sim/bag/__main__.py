"""``python -m fohssv_sim.bag info|check|repair BAG``.

Exit codes: 0 success; 1 the path is not a (sound) bag, with a one-line ``error:`` on stderr;
2 bad usage. Never a traceback for a bad bag.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence

from mcap.reader import make_reader

from .. import contract
from .check import main_check
from .loader import BagError, locate, run_metadata
from .repair import main_repair
from .run import ContractChannels, problems_of
from .stream import float64_array, read_arrays, summary_counts

USAGE = '''usage: python -m fohssv_sim.bag COMMAND BAG
  info BAG     what the run holds: topics, counts, times, run metadata (reads cut bags too)
  check BAG    structural check (CRCs, indexes, summary, metadata.yaml); exit 1 on a problem
  repair BAG   rebuild index, summary and metadata.yaml of a bag whose recorder was killed'''


class _Ends:
    """A column that keeps only the first and the last row (``info`` of a bag without a
    summary: the state's time span in constant memory)."""

    def __init__(self, width: int) -> None:
        self.width, self.n, self.seen, self.rejected = width, 0, 0, 0
        self.first = self.last = None

    def add(self, values, log_time: int) -> None:
        if self.first is None:
            self.first = values
        self.last = values
        self.n += 1


def _state_span(files, topics) -> tuple[int, float, float]:
    """(states, first t, last t) from the summary and the first and last state messages; None
    when a file has no summary."""
    n, first, last = 0, float('nan'), float('nan')
    for path in files.mcap_files:
        found = summary_counts(path)
        if found is None:
            return None
        names = [t for t in found[0] if topics.wants(contract.STATE.name, t)]
        n += sum(found[0][t] for t in names)
        if not names:
            continue
        with path.open('rb') as f:
            reader = make_reader(f)
            for reverse in (False, True):
                for _, _, msg in reader.iter_messages(topics=names, reverse=reverse):
                    got = float64_array(msg.data)
                    if got is not None:
                        t = got[0][0]
                        first = t if not first <= t else first
                        last = t if not last >= t else last
                        break
    return n, first, last


def info(path: str) -> list[str]:
    """What ``info`` prints: from the MCAP summary section (counts, the state's span, the run
    metadata) without reading the messages; a bag without a summary (its recorder was
    killed) is read through once, in constant memory."""
    files = locate(path)
    topics = ContractChannels(files.directory, None)
    span = _state_span(files, topics)
    summaries = [summary_counts(f) for f in files.mcap_files]
    problem = ''
    if span is not None and all(summaries):
        counts: dict[str, int] = {}
        for found in summaries:
            for topic, c in found[0].items():
                counts[topic] = counts.get(topic, 0) + c
        records = [m for found in summaries for m in found[3]]
        n, first, last = span
    else:
        counts, records = {}, []
        ends = _Ends(len(contract.STATE.fields))
        reads = [read_arrays(mcap_path, lambda c, s: 0 if topics.wants(
            contract.STATE.name, c.topic) else None, [ends], [None])
            for mcap_path in files.mcap_files]
        problem = (problems_of(reads) or [''])[0]
        for got in reads:
            for cid, (topic, _, _) in got.channels.items():
                counts[topic] = counts.get(topic, 0) + got.counts.get(cid, 0)
            records += got.metadata
        n = ends.n
        first = ends.first[0] if ends.first else float('nan')
        last = ends.last[0] if ends.last else float('nan')
    lines = [f'bag:      {path}',
             f'state:    {n} samples, t = {first:.9g} ... {last:.9g} s']
    lines += [f'topic:    {topic}: {c} messages' for topic, c in counts.items()]
    metadata = run_metadata(files.info, records)
    for key in sorted(metadata):
        value = metadata[key]
        text = value if isinstance(value, str) else repr(value)
        lines.append(f'metadata: {key} = {text if len(text) <= 200 else text[:197] + "..."}')
    if problem:
        lines += [f'WARNING: truncated bag: {problem}',
                  f'         repair it with: python -m fohssv_sim.bag repair {path}']
    return lines


def main_info(argv: Sequence[str]) -> int:
    """``info BAG``: summary of the run (:func:`info`)."""
    if len(argv) != 1:
        print('usage: python -m fohssv_sim.bag info BAG', file=sys.stderr)
        return 2
    try:
        lines = info(argv[0])
    except BagError as exc:
        print(f'error: {exc}', file=sys.stderr)
        return 1
    print('\n'.join(lines))
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
