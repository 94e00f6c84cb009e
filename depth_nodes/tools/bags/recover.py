"""A recording cut off (a SIGKILL, a full disk, a power loss) made a complete bag again,
every complete message kept bit for bit: `depth-nodes reindex` (rosbag2's ``ros2 bag
reindex``, which rosbags does not have).

A cut MCAP file has no summary, no footer and (written at the end too) no metadata.yaml,
and rosbags refuses it. :func:`reindex_bag` reads each MCAP file of the bag from its start
(:func:`~depth_nodes.tools.bags.mcap_scan.scan_mcap`: the whole chunks whose CRC holds,
and the complete messages of the chunk it was cut inside) and writes what it holds as a
complete bag (:class:`~depth_nodes.tools.bags.io.BagWriter`: zstd chunks with their CRC,
summary, footer, metadata.yaml): each message's bytes, topic, type and timestamp as they
were, each topic's offered QoS and message definition as recorded. In place by default:
the cut file is kept beside the recovered one as ``<file>.cut``; or into another folder,
the bag left as it is. A bag that opens as it is is left alone.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from rosbags.rosbag2.metadata import parse_qos

from depth_nodes.errors import BagError
from depth_nodes.tools.bags.io import BagReader, BagWriter
from depth_nodes.tools.bags.mcap_scan import Channel, Message, ScanEnd, Schema, scan_mcap

#: The suffix a cut file is kept under after an in-place reindex.
CUT_SUFFIX = '.cut'


@dataclass
class Reindexed:
    """What :func:`reindex_bag` did.

    Attributes:
        bag: The complete bag (the one given, or ``out``).
        counts: Messages recovered, by topic (empty: the bag was complete already).
        scans: Each MCAP file read and how far its scan got.
        kept: The cut files kept beside the recovered one (in place).
        orphans: Messages skipped because their channel record was lost with a damaged
            chunk.
    """

    bag: Path
    counts: Counter[str] = field(default_factory=Counter)
    scans: list[tuple[Path, ScanEnd]] = field(default_factory=list)
    kept: list[Path] = field(default_factory=list)
    orphans: int = 0

    @property
    def complete_already(self) -> bool:
        """The bag opened as it was: nothing was done."""
        return not self.scans

    def format(self) -> str:
        """What happened, for the command line."""
        if self.complete_already:
            return f'{self.bag} is complete (it opens as it is): nothing to recover'
        lines = [f'recovered {sum(self.counts.values())} messages on {len(self.counts)} '
                 f'topics into {self.bag}']
        for path, end in self.scans:
            lost = end.size - end.offset
            state = 'complete' if end.complete else (
                f'cut off: read up to {end.reason}, the last {lost} bytes lost')
            extra = [f'{end.damaged} damaged chunk(s) skipped'] if end.damaged else []
            if end.cut_chunk_messages:
                extra.append(f'{end.cut_chunk_messages} message(s) from the chunk it was '
                             'cut inside')
            lines.append(f'  {path.name}: {end.chunks} whole chunk(s), {state}'
                         f'{"; " + "; ".join(extra) if extra else ""}')
        if self.orphans:
            lines.append(f'  {self.orphans} message(s) skipped: their topic was in a '
                         'damaged chunk')
        for path in self.kept:
            lines.append(f'  the cut file is kept as {path} (delete it once the '
                         'recovered bag is checked)')
        return '\n'.join(lines)


def _opens(bag: Path) -> bool:
    if not (bag / 'metadata.yaml').is_file():
        return False
    try:
        BagReader(bag).close()
    except BagError:
        return False
    return True


def mcap_files(bag: Path) -> list[Path]:
    """The MCAP files of a bag folder, in name order.

    Raises:
        BagError: No such folder, or no MCAP file in it.
    """
    if not bag.is_dir():
        raise BagError(f'bag not found: {bag}' if not bag.exists() else
                       f'{bag} is a file: reindex takes the bag folder')
    files = sorted(p for p in bag.glob('*.mcap') if p.is_file())
    if not files:
        other = ' (an sqlite3 bag survives a crash as it is)' if any(bag.glob('*.db3')) else ''
        raise BagError(f'no MCAP file in {bag}: reindex recovers MCAP recordings{other}')
    return files


def reindex_bag(path: str | Path, out: str | Path | None = None, *,
                overwrite: bool = False) -> Reindexed:
    """Make a cut recording a complete bag again (see the module docstring).

    Args:
        path: The bag folder.
        out: Write the recovered bag here and leave ``path`` as it is; None: in place,
            each cut file kept as ``<file>.cut``.
        overwrite: Replace an existing ``out``.

    Raises:
        BagError: No bag, no MCAP file, not MCAP, no complete message in it, or ``out``
            exists.
    """
    bag = Path(path)
    files = mcap_files(bag)
    if out is None and _opens(bag):
        return Reindexed(bag)
    if out is not None:
        return _recover(files, BagWriter(Path(out), overwrite=overwrite))
    # beside the bag, so that the files move into it by renaming
    work = Path(tempfile.mkdtemp(prefix=f'.{bag.name}.reindex-', dir=bag.parent))
    try:
        result = _recover(files, BagWriter(work / bag.name))
        result.kept = _swap_in(bag, files, work / bag.name)
        result.bag = bag
        return result
    finally:
        shutil.rmtree(work, ignore_errors=True)


def _recover(files: list[Path], writer: BagWriter) -> Reindexed:
    result = Reindexed(writer.path)
    try:
        for file in files:
            result.scans.append((file, _copy(file, writer, result)))
        if not result.counts:
            reasons = '; '.join(f'{f.name}: read up to {e.reason}' for f, e in result.scans)
            raise BagError(f'no complete message in {files[0].parent}: nothing to recover '
                           f'({reasons})')
        writer.close()
    except BaseException:
        writer.discard()
        raise
    return result


def _copy(file: Path, writer: BagWriter, result: Reindexed) -> ScanEnd:
    """Write the messages of one MCAP file; returns how far its scan got."""
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    for record in scan_mcap(file):
        if isinstance(record, Schema):
            schemas[record.id] = record
        elif isinstance(record, Channel):
            channels[record.id] = record
        elif isinstance(record, Message):
            channel = channels.get(record.channel_id)
            schema = schemas.get(channel.schema_id) if channel is not None else None
            if channel is None or schema is None:
                result.orphans += 1
                continue
            writer.add_topic(channel.topic, schema.name, qos=_offered(channel),
                             msgdef=schema.data.decode(errors='replace'))
            writer.write(channel.topic, record.data, record.log_time, schema.name)
            result.counts[channel.topic] += 1
        else:
            return record
    raise AssertionError('scan_mcap ends with a ScanEnd')  # pragma: no cover


def _offered(channel: Channel) -> list[Any]:
    """The QoS profiles a channel's metadata says its publishers offered (none if it
    cannot be read)."""
    try:
        return parse_qos(channel.metadata.get('offered_qos_profiles', ''))
    except Exception:  # rosbags' ReaderError on bad YAML: the QoS is not worth the data
        return []


def _swap_in(bag: Path, cut: list[Path], recovered: Path) -> list[Path]:
    """Put the recovered bag's files in ``bag``, each cut file renamed ``<file>.cut``
    first; returns those. The new files are on the disk before anything is renamed."""
    for item in recovered.iterdir():
        with item.open('rb') as f:
            os.fsync(f.fileno())
    kept = []
    for file in cut:
        kept.append(file.with_name(file.name + CUT_SUFFIX))
        file.rename(kept[-1])
    for item in recovered.iterdir():
        item.replace(bag / item.name)
    return kept
