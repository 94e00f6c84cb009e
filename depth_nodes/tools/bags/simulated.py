"""Bags written from a simulator: its configuration in the bag's metadata (``custom_data``),
whole frames up to a signal; read back with that configuration (the time-of-flight and
depth-camera bags)."""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Generic, TypeVar

from depth_nodes.errors import BagError, ConfigError
from depth_nodes.tools.bags.io import BagReader, BagWriter
from depth_nodes.tools.signals import stop_requested

C = TypeVar('C')
#: zstd level of the simulated bags (small committed files).
COMPRESSION_LEVEL = 19
#: One frame: its stamp and its (topic, message) pairs.
Frame = tuple[int, list[tuple[str, Any]]]


@dataclass(frozen=True)
class SimulatedBag(Generic[C]):
    """One kind of simulated bag.

    Attributes:
        key: The metadata key of the configuration (JSON of the config dataclass).
        what: What such a bag is, for errors (``a time-of-flight bag``).
        made_by: The command that makes one, for errors.
        parse: The validated configuration of the JSON document.
    """

    key: str
    what: str
    made_by: str
    parse: Callable[[dict[str, Any]], C]

    def write(self, path: str | Path, config: Any, frames: Iterable[Frame], *,
              overwrite: bool = False) -> int:
        """Write ``config`` and ``frames`` at ``path``; returns the number of messages. A
        SIGINT / SIGTERM stops between frames.

        Raises:
            BagError: ``path`` exists and ``overwrite`` is False.
        """
        count = 0
        with BagWriter(path, overwrite=overwrite, compression_level=COMPRESSION_LEVEL) as writer:
            writer.set_custom_data(self.key, json.dumps(dataclasses.asdict(config)))
            for stamp, messages in frames:
                if stop_requested():  # whole frames only
                    break
                for topic, msg in messages:
                    writer.write(topic, msg, stamp)
                    count += 1
        return count

    def config(self, custom_data: dict[str, str], path: str | Path) -> C:
        """The configuration a bag of this kind (or one processed from it) records.

        Raises:
            BagError: No such metadata, or it does not parse.
        """
        if self.key not in custom_data:
            raise BagError(f'{path} is not {self.what} (no {self.key} metadata: made by '
                           f'{self.made_by}, then process)')
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
