"""Structural check of a bag: the MCAP container is checked by ``pymcap-cli doctor``, the
ROS 2 layer and ``metadata.yaml`` by fohssv.

For every MCAP file, ``pymcap-cli doctor`` (run as a program, its JSONL findings read back)
checks the container against the MCAP specification: magic at both ends, every record
parses in order with the header first and the footer last, chunk, data-section and summary
CRCs, chunk indexes and message indexes point at the chunks and messages they describe
(offsets, lengths, times, channels), statistics equal its recount, metadata indexes and
summary offsets point at their records. Each error and warning it reports is a problem
(grouped by finding code); its info findings (no compression, ...) are not.

fohssv adds, reading with ``mcap``: header profile ``ros2``; channels name existing
``ros2msg``/``ros2idl`` schemas and ``cdr`` encoding; every message decodes with
``mcap_ros2``'s decoder. For ``metadata.yaml``: every field ``ros2 bag info`` reads, and its
counts, start, duration, topic types and type hashes equal the MCAP's. Pure: no rclpy.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from .loader import BagError, locate

__all__ = ['CheckReport', 'check', 'REQUIRED_METADATA_FIELDS']

#: metadata.yaml fields ``ros2 bag info`` (rosbag2_storage's YAML reader, version 9) reads.
REQUIRED_METADATA_FIELDS = ('version', 'storage_identifier', 'duration', 'starting_time',
                            'message_count', 'topics_with_message_count', 'compression_format',
                            'compression_mode', 'relative_file_paths', 'files', 'custom_data',
                            'ros_distro')
_TOPIC_FIELDS = ('name', 'type', 'serialization_format', 'offered_qos_profiles',
                 'type_description_hash')
#: doctor finding codes of a file cut short (a killed recorder) or with unreadable data:
#: ``repair`` rebuilds it from what precedes the damage.
_REPAIRABLE = {'FILE_TOO_SMALL', 'BAD_TRAILING_MAGIC', 'MISSING_FOOTER', 'MISSING_DATA_END',
               'TRUNCATED_RECORD_HEADER', 'TRUNCATED_RECORD_BODY', 'RECORD_PARSE_ERROR',
               'TRUNCATED_CHUNK_RECORD_HEADER', 'TRUNCATED_CHUNK_RECORD_BODY',
               'CHUNK_CRC_MISMATCH', 'CHUNK_DECOMPRESSION_FAILED', 'DATA_SECTION_CRC_MISMATCH'}


@dataclass
class CheckReport:
    """Problems found (empty = the bag is sound) and facts worth printing."""

    bag: Path
    problems: list[str] = field(default_factory=list)
    facts: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not self.problems


def _doctor(path: Path) -> tuple[dict, list[dict]] | str:
    """(summary, findings) of ``pymcap-cli doctor --format jsonl path``, or why it failed.

    Raises:
        FileNotFoundError: pymcap-cli is not installed.
    """
    exe = Path(sys.executable).parent / 'pymcap-cli'
    exe = str(exe) if exe.is_file() else shutil.which('pymcap-cli')
    if exe is None:
        raise FileNotFoundError('pymcap-cli not found; bag check needs it (it is pinned in '
                                'requirements.txt)')
    out = subprocess.run([exe, 'doctor', '--format', 'jsonl', str(path)], capture_output=True,
                         text=True, encoding='utf-8', errors='replace', check=False)
    lines = [json.loads(line) for line in out.stdout.splitlines() if line.startswith('{')]
    summary = [r for r in lines if r.get('type') == 'summary']
    if len(summary) != 1:
        return f'exit {out.returncode}: {(out.stderr.strip().splitlines() or [""])[-1]}'
    return summary[0], [r for r in lines if r.get('type') == 'finding']


def _check_container(path: Path, p: list[str]) -> dict | None:
    """The doctor's errors and warnings on ``path`` as problems, one per finding code: its
    summary, or None when it found an error (the file is not read further)."""
    res = _doctor(path)
    if isinstance(res, str):
        p.append(f'{path.name}: pymcap-cli doctor could not examine it ({res})')
        return None
    summary, findings = res
    groups: dict[tuple[str, str], list[dict]] = {}
    for f in findings:
        if f['severity'] in ('error', 'warning'):
            groups.setdefault((f['severity'], f['code']), []).append(f)
    for (severity, code), same in groups.items():
        at = '' if same[0]['offset'] is None else f" at byte {same[0]['offset']}"
        more = f' (and {len(same) - 1} more)' if len(same) > 1 else ''
        p.append(f"{path.name}: {severity} {code}{at}: {same[0]['message']}{more}")
    if _REPAIRABLE & {code for _, code in groups}:
        p.append(f'{path.name}: truncated or corrupt; run: python -m fohssv_sim.bag repair')
    return None if summary['errors'] else summary


def _check_channels(summary, name: str, p: list[str]) -> None:
    for chan in summary.channels.values():
        if chan.schema_id not in summary.schemas:
            p.append(f'{name}: channel {chan.topic} names missing schema {chan.schema_id}')
        elif summary.schemas[chan.schema_id].encoding not in ('ros2msg', 'ros2idl'):
            p.append(f'{name}: schema of {chan.topic} has encoding '
                     f'{summary.schemas[chan.schema_id].encoding!r}')
        if chan.message_encoding != 'cdr':
            p.append(f'{name}: channel {chan.topic} encoding {chan.message_encoding!r} != cdr')


def _check_decodes(reader, name: str, p: list[str]) -> None:
    topic = '?'
    try:
        for _schema, chan, _msg, _decoded in reader.iter_decoded_messages(log_time_order=False):
            topic = chan.topic
    except Exception as exc:  # noqa: BLE001 - any decoder failure is a finding
        p.append(f'{name}: a message after one on {topic} does not decode with mcap_ros2 '
                 f'({type(exc).__name__}: {exc})')


def _check_mcap(path: Path, report: CheckReport
                ) -> tuple[Counter, int, int, dict[str, tuple[str, str]]] | None:
    """The container check, then fohssv's: profile, encodings, every message decodes. The
    per-topic counts, first and last log time, and per-topic (type, type hash); None when
    the file is not sound enough to read."""
    p, name = report.problems, path.name
    doctor = _check_container(path, p)
    if doctor is None:
        return None
    report.facts.append(f'{name}: {path.stat().st_size} bytes, {doctor["records"]} records; '
                        'pymcap-cli doctor: record structure, chunk and data CRCs valid, '
                        'indexes and statistics consistent')
    with path.open('rb') as f:
        try:
            reader = make_reader(f, decoder_factories=[DecoderFactory()])
            profile, summary = reader.get_header().profile, reader.get_summary()
        except (McapError, ValueError) as exc:
            p.append(f'{name}: header or summary unreadable with mcap ({exc})')
            return None
        if profile != 'ros2':
            p.append(f'{name}: header profile {profile!r}, expected ros2')
        if summary is None or summary.statistics is None:
            p.append(f'{name}: no summary or no statistics record')
            return None
        _check_channels(summary, name, p)
        _check_decodes(reader, name, p)
    stats = summary.statistics
    report.facts.append(f'{name}: {stats.message_count} messages on {len(summary.channels)} '
                        f'channels, {stats.metadata_count} metadata records, all decode')
    topics: Counter = Counter({c.topic: 0 for c in summary.channels.values()})
    for cid, n in stats.channel_message_counts.items():
        topics[summary.channels[cid].topic] += n
    hashes = {c.topic: (summary.schemas[c.schema_id].name if c.schema_id in summary.schemas
                        else '', c.metadata.get('topic_type_hash', ''))
              for c in summary.channels.values()}
    return topics, stats.message_start_time, stats.message_end_time, hashes


def _check_metadata_yaml(info: dict, topics: Counter, t0: int, t1: int,
                         hashes: dict[str, tuple[str, str]], report: CheckReport) -> None:
    p = report.problems
    missing = [f for f in REQUIRED_METADATA_FIELDS if f not in info]
    if missing:
        p.append(f'metadata.yaml: missing {missing}')
        return
    if info['version'] != 9:
        p.append(f"metadata.yaml: version {info['version']}, expected 9")
    try:
        start = info['starting_time']['nanoseconds_since_epoch']
        duration = info['duration']['nanoseconds']
    except (KeyError, TypeError):
        p.append('metadata.yaml: starting_time/duration lack their nanoseconds fields')
        return
    total = sum(topics.values())
    if info['message_count'] != total:
        p.append(f"metadata.yaml: message_count {info['message_count']} != {total} in MCAP")
    if total and (start, duration) != (t0, t1 - t0):
        p.append(f'metadata.yaml: starting_time/duration {start}/{duration} != MCAP '
                 f'{t0}/{t1 - t0}')
    listed = {}
    for entry in info['topics_with_message_count'] or []:
        tm = entry.get('topic_metadata', {})
        lack = [f for f in _TOPIC_FIELDS if f not in tm]
        if lack or 'message_count' not in entry:
            p.append(f"metadata.yaml: topic {tm.get('name')} lacks {lack or ['message_count']}")
            continue
        listed[tm['name']] = entry['message_count']
        if tm['name'] in hashes:
            msgtype, rihs = hashes[tm['name']]
            if tm['type'] != msgtype:
                p.append(f"metadata.yaml: {tm['name']} type {tm['type']} != MCAP {msgtype}")
            if rihs and tm['type_description_hash'] != rihs:
                p.append(f"metadata.yaml: {tm['name']} type hash differs from the MCAP's")
    if listed != dict(topics):
        p.append(f'metadata.yaml: topic counts {listed} != MCAP {dict(topics)}')
    for f in info['files'] or []:
        if not {'path', 'starting_time', 'duration', 'message_count'} <= set(f):
            p.append(f'metadata.yaml: files entry {f} lacks fields')


def check(path: str | Path) -> CheckReport:
    """Check the bag at ``path``; the report lists every problem found.

    Raises:
        BagError: the path is not a bag at all (see :func:`.loader.locate`).
        FileNotFoundError: pymcap-cli is not installed.
    """
    files = locate(path)
    report = CheckReport(files.directory)
    total: Counter = Counter()
    t0, t1 = None, None
    hashes: dict[str, tuple[str, str]] = {}
    for mcap_path in files.mcap_files:
        res = _check_mcap(mcap_path, report)
        if res is None:
            continue
        topics, lo, hi, file_hashes = res
        total.update(topics)
        hashes.update(file_hashes)
        if sum(topics.values()):
            t0 = lo if t0 is None else min(t0, lo)
            t1 = hi if t1 is None else max(t1, hi)
    if files.info is None:
        report.problems.append(f'{files.directory}: no metadata.yaml; run: python -m '
                               'fohssv_sim.bag repair')
    elif not report.problems:
        _check_metadata_yaml(files.info, total, t0 or 0, t1 or 0, hashes, report)
    return report


def main_check(argv: list[str]) -> int:
    """``check BAG``: print the facts and problems; exit 0 if sound, 1 otherwise."""
    if len(argv) != 1:
        print('usage: python -m fohssv_sim.bag check BAG', file=sys.stderr)
        return 2
    try:
        report = check(argv[0])
    except BagError as exc:
        print(f'error: {exc}', file=sys.stderr)
        return 1
    for fact in report.facts:
        print(fact)
    for problem in report.problems:
        print(f'problem: {problem}')
    print(f'{report.bag}: ' + ('OK' if report.ok else f'{len(report.problems)} problem(s)'))
    return 0 if report.ok else 1

