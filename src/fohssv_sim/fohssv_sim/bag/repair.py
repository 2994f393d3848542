"""Rebuild what a killed recorder could not write: the MCAP summary and indexes, and
``metadata.yaml``.

:func:`repair` reads every complete chunk of the bag (:func:`.loader.scan`) twice, as a
stream (memory: a chunk at a time, whatever the bag's length): once to learn its channels,
metadata and where it is cut, once to copy its messages into a new,
fully indexed MCAP with the same channels, schemas, messages, log times and run metadata
(plus ``fohssv.repaired``, saying what was recovered), and a version 9 ``metadata.yaml``
(custom_data from the run metadata). The original MCAP file is kept as ``<name>.orig``
unless ``backup=False``. A bag that is already complete is left alone unless ``force``.
All or nothing: every check comes first, the new files are written beside the bag, and if
putting them in place fails the original is restored (``BagError`` says the bag is unchanged).
Every file the bag names must lie inside its folder (:func:`.loader.locate` refuses
``relative_file_paths`` such as ``../other/x.mcap``).

CLI: ``python -m fohssv_sim.bag repair BAG`` (:func:`main_repair`). Pure: no rclpy.
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from rosbags.rosbag2.metadata import parse_qos
from ruamel.yaml import YAML

from .loader import BagError, scan
from .writer import RunWriter, is_run_metadata, typestore

__all__ = ['RepairReport', 'repair', 'main_repair']


@dataclass(frozen=True)
class RepairReport:
    """What :func:`repair` did."""

    bag: Path
    repaired: bool
    messages: int
    summary: str
    backup: Path | None = None


def _rihs01(msgtype: str, channel_hash: str) -> str:
    if channel_hash.startswith('RIHS01_'):
        return channel_hash
    try:
        return typestore().hash_rihs01(msgtype)
    except Exception:  # noqa: BLE001 - a type the typestore does not know
        return 'RIHS01_' + '0' * 64


def repair(path: str | Path, *, backup: bool = True, force: bool = False) -> RepairReport:
    """Rebuild the bag at ``path`` in place from what is readable.

    Raises:
        BagError: not a bag, several MCAP files, or nothing readable.
    """
    sc = scan(path, on_message=lambda cid, log_time, data: None)    # counted, not kept
    files = sc.files
    if len(files.mcap_files) != 1:
        raise BagError(f'{files.directory}: repair handles a bag with one MCAP file, found '
                       f'{len(files.mcap_files)}')
    mcap_path = files.mcap_files[0]
    if sc.complete and files.metadata_yaml is not None and not force:
        return RepairReport(files.directory, False, sc.message_count,
                            f'{files.directory}: complete (summary, index and metadata.yaml '
                            'present); nothing to repair')
    what = ('complete MCAP, missing metadata.yaml' if sc.complete else
            f'recovered {sc.message_count} messages from the first {sc.bytes_read} of '
            f'{sc.bytes_total} bytes ({sc.problem})')
    tmp_parent = Path(tempfile.mkdtemp(prefix=f'.{files.directory.name}.repair-',
                                       dir=files.directory.parent))
    try:
        new_bag = tmp_parent / mcap_path.stem
        writer = RunWriter(new_bag).open()
        topic_of = {}
        for chan in sc.channels.values():
            try:
                qos = parse_qos(chan.metadata.get('offered_qos_profiles', '') or '[]')
            except Exception:  # noqa: BLE001 - unparsable QoS text: keep the topic without it
                qos = []
            writer.add_topic(chan.topic, chan.msgtype, qos=qos, msgdef=chan.schema,
                             rihs01=_rihs01(chan.msgtype, chan.metadata.get('topic_type_hash',
                                                                            '')))
            topic_of[chan.id] = chan.topic
        meta: dict[str, str] = {}
        for name, values in sc.metadata_records:
            if is_run_metadata(name):
                meta.update(values)
        if files.info is not None:
            for key, value in (files.info.get('custom_data') or {}).items():
                meta.setdefault(str(key), str(value))
        meta['fohssv.repaired'] = what
        writer.add_metadata(meta)
        copied = scan(path, on_message=lambda cid, log_time, data: writer.write(
            topic_of[cid], log_time, data))
        if copied.message_count != sc.message_count:      # the bag changed between the reads
            raise BagError(f'{files.directory}: changed while it was repaired (read '
                           f'{sc.message_count}, then {copied.message_count} messages); the '
                           'bag is unchanged')
        writer.close()
        new_mcap = writer.mcap_path
        new_yaml = new_bag / 'metadata.yaml'
        if new_mcap.name != mcap_path.name:
            _rename_in_metadata(new_yaml, new_mcap.name, mcap_path.name)
        saved = None
        if backup:
            saved = mcap_path.with_name(mcap_path.name + '.orig')
            n = 1
            while saved.exists():
                saved = mcap_path.with_name(f'{mcap_path.name}.orig{n}')
                n += 1
        _install(mcap_path, new_mcap, new_yaml, files.directory / 'metadata.yaml',
                 saved or tmp_parent / 'original.mcap')
        if not backup:
            saved = None
    except OSError as exc:
        raise BagError(f'{files.directory}: repair failed, the bag is unchanged ({exc})'
                       ) from None
    finally:
        shutil.rmtree(tmp_parent, ignore_errors=True)
    return RepairReport(files.directory, True, sc.message_count,
                        f'{files.directory}: rebuilt index, summary and metadata.yaml; {what}',
                        saved)


def _install(mcap_path: Path, new_mcap: Path, new_yaml: Path, yaml_path: Path,
             keep: Path) -> None:
    """Put the rebuilt MCAP and metadata.yaml in place, all or nothing: the original MCAP
    moves to ``keep`` first; if a later step fails, it moves back and the error is raised
    with the bag as it was (the old metadata.yaml is replaced last, atomically)."""
    if yaml_path.exists() and not yaml_path.is_file():
        raise IsADirectoryError(f'{yaml_path} is not a file')
    mcap_path.replace(keep)
    try:
        new_mcap.replace(mcap_path)
        new_yaml.replace(yaml_path)
    except OSError:
        keep.replace(mcap_path)
        raise


def _rename_in_metadata(meta: Path, old: str, new: str) -> None:
    yaml = YAML(typ='safe', pure=True)
    yaml.default_flow_style = False
    data = yaml.load(meta.read_text('utf8'))
    info = data['rosbag2_bagfile_information']
    info['relative_file_paths'] = [new if p == old else p for p in info['relative_file_paths']]
    for f in info.get('files', []):
        if f.get('path') == old:
            f['path'] = new
    with meta.open('w', encoding='utf8') as out:
        yaml.dump(data, out)


class _OneLineParser(argparse.ArgumentParser):
    """Usage errors in one line (exit 2), as every fohssv command gives them."""

    def error(self, message: str) -> None:  # type: ignore[override]
        self.exit(2, f'usage: {self.prog} BAG [--no-backup] [--force]: {message}\n')


def main_repair(argv: Sequence[str] | None = None) -> int:
    """``repair BAG [--no-backup] [--force]``: exit 0 when repaired or nothing to do, 1 with a
    one-line error on stderr when the path is not a repairable bag."""
    parser = _OneLineParser(
        prog='python -m fohssv_sim.bag repair',
        description='Rebuild the MCAP index/summary and metadata.yaml of a bag whose recorder '
                    'was killed, from every complete chunk.')
    parser.add_argument('bag', help='bag directory (or its .mcap file)')
    parser.add_argument('--no-backup', action='store_true',
                        help='do not keep the original MCAP file as <name>.orig')
    parser.add_argument('--force', action='store_true', help='rewrite even a complete bag')
    args = parser.parse_args(argv)
    try:
        report = repair(args.bag, backup=not args.no_backup, force=args.force)
    except BagError as exc:
        print(f'error: {exc}', file=sys.stderr)
        return 1
    print(report.summary)
    if report.backup is not None:
        print(f'original kept as {report.backup}')
    return 0
