"""Bags written from a simulator: its configuration in the bag's metadata (``custom_data``),
whole frames up to a signal; read back with that configuration. Every simulated kind (stereo,
structured light, time of flight, multi-view sequences, depth cameras) is one
:class:`SimulatedBag`."""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Generic, TypeVar

from std_msgs.msg import Header

from depth_nodes.core.stamps import stamp_parts
from depth_nodes.errors import BagError, ConfigError
from depth_nodes.tools.bags.io import BagReader, BagWriter
from depth_nodes.tools.signals import stop_requested

C = TypeVar('C')
#: zstd level of the simulated bags (slow to write, but the float ground truth shrinks ~40 %:
#: small committed files).
COMPRESSION_LEVEL = 19
#: One frame: its stamp (the bag timestamp of every message in it) and its (topic, message)
#: pairs, in writing order.
Frame = tuple[int, list[tuple[str, Any]]]


def stamped_header(stamp_ns: int, frame_id: str) -> Header:
    """A std_msgs/Header at ``stamp_ns`` nanoseconds in ``frame_id``."""
    header = Header(frame_id=frame_id)
    header.stamp.sec, header.stamp.nanosec = stamp_parts(stamp_ns)
    return header


@dataclass(frozen=True)
class SimulatedBag(Generic[C]):
    """One kind of simulated bag.

    Attributes:
        key: The metadata key of the configuration (JSON of the config dataclass).
        what: What such a bag is, for errors (``a time-of-flight bag``).
        made_by: The command(s) that make one, for errors (``depth-nodes generate
            --preset tof_vga, then process``).
        parse: The validated configuration of the JSON document.
    """

    key: str
    what: str
    made_by: str
    parse: Callable[[dict[str, Any]], C]

    def write(self, path: str | Path, config: Any, frames: Iterable[Frame], *,
              overwrite: bool = False,
              on_complete: Callable[[Path], None] | None = None) -> int:
        """Write ``config`` and ``frames`` at ``path``; returns the number of messages. A
        SIGINT / SIGTERM stops between frames.

        Args:
            on_complete: Called with the bag's folder once the bag is closed with every
                frame in it (not after a signal): for a file beside the bag.

        Raises:
            BagError: ``path`` exists and ``overwrite`` is False.
        """
        return self.write_groups(path, config, ([frame] for frame in frames),
                                 overwrite=overwrite, on_complete=on_complete)

    def write_groups(self, path: str | Path, config: Any, groups: Iterable[Iterable[Frame]], *,
                     overwrite: bool = False,
                     on_complete: Callable[[Path], None] | None = None) -> int:
        """:meth:`write` for frames that are of use only together (a structured-light
        pattern sequence): a signal stops between groups, never inside one. A group is
        iterated only once the signal has been checked, so a lazy one simulates nothing
        after it.
        """
        count = 0
        with BagWriter(path, overwrite=overwrite, compression_level=COMPRESSION_LEVEL) as writer:
            writer.set_custom_data(self.key, json.dumps(dataclasses.asdict(config)))
            for group in groups:
                if stop_requested():  # whole groups only
                    return count
                for stamp, messages in group:
                    for topic, msg in messages:
                        writer.write(topic, msg, stamp)
                        count += 1
        if on_complete is not None:
            on_complete(Path(path))
        return count

    def config(self, custom_data: dict[str, str], path: str | Path) -> C:
        """The configuration a bag of this kind (or one processed from it) records.

        Raises:
            BagError: No such metadata, or it does not parse.
        """
        if self.key not in custom_data:
            raise BagError(f'{path} is not {self.what} (no {self.key} metadata: made by '
                           f'{self.made_by})')
        try:
            return self.parse(json.loads(custom_data[self.key]))
        except (ValueError, TypeError, KeyError, ConfigError) as exc:
            raise BagError(f'{path}: malformed {self.key} metadata: {exc}') from None

    def read(self, path: str | Path, topics: list[str], *, optional: tuple[str, ...] = ()
             ) -> tuple[C, dict[str, dict[int, Any]]]:
        """The configuration of a bag of this kind and the messages, by bag timestamp, of
        ``topics`` (those in ``optional`` may be missing).

        Raises:
            BagError: No bag, not this kind, or a topic missing.
        """
        with BagReader(Path(path)) as reader:
            config = self.config(dict(reader.custom_data), path)
            for topic in topics:
                if topic not in optional:
                    reader.require(topic)
            present = [t for t in topics if t in reader.topics]
            found: dict[str, dict[int, Any]] = {t: {} for t in topics}
            for m in reader.messages(present):
                found[m.topic][m.timestamp] = m.deserialize()
        return config, found
