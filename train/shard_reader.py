"""The samples of one tar shard, reading only those a loader slot takes.

A loader slot (one worker of one rank) takes every n-th sample when a category has fewer shards
than slots, which is the rule on a GPU machine (15 workers, 4 airplane shards). Streaming the
tar would make every slot read every sample's bytes to keep a fifteenth of them. Here the tar's
headers are walked once per shard (``index_shard``: each sample's members lie together, so a
sample is one byte range) and a slot reads only its own samples' ranges (``read_samples``).

Samples are grouped as webdataset groups them: the key is a member's path up to the first '.'
of its file name, the rest, lower-cased, names the member; ``__key__`` and ``__url__`` come
with each sample. A cut-off shard raises ``tarfile.ReadError("unexpected end of data")``, as a
streamed read would, also where a streamed read misses it (a cut between two members).
"""

from __future__ import annotations

import dataclasses
import os
import re
import tarfile
from pathlib import Path
from typing import Iterable, Iterator

_NAME = re.compile(r"^((?:.*/|)[^./]+)[.]([^/]*)$")  # (key, member suffix), webdataset's split


@dataclasses.dataclass(frozen=True)
class SampleSpan:
    """One sample of a shard: its key and, per member, (suffix, data offset, size) in bytes."""

    key: str
    members: tuple[tuple[str, int, int], ...]

    @property
    def start(self) -> int:
        return self.members[0][1]

    @property
    def end(self) -> int:
        return self.members[-1][1] + self.members[-1][2]


def _cut_off() -> tarfile.ReadError:
    return tarfile.ReadError("unexpected end of data")


def index_shard(path: str | Path) -> list[SampleSpan]:
    """Every sample of the tar at ``path``, in file order, from its headers alone."""
    size = os.path.getsize(path)
    spans: list[SampleSpan] = []
    key, members = None, []
    with tarfile.open(path, "r:") as tar:
        for info in tar:
            if not info.isfile():
                continue
            found = _NAME.match(info.name)
            if not found:
                continue
            if info.offset_data + info.size > size:
                raise _cut_off()
            if found.group(1) != key:
                if members:
                    spans.append(SampleSpan(key, tuple(members)))
                key, members = found.group(1), []
            members.append((found.group(2).lower(), info.offset_data, info.size))
        # the walk stops quietly at a header cut in two or at a cut between members; a whole tar
        # ends with zero blocks after its last member
        if size - tar.offset < tarfile.BLOCKSIZE:
            raise _cut_off()
    if members:
        spans.append(SampleSpan(key, tuple(members)))
    return spans


def read_samples(path: str | Path, spans: Iterable[SampleSpan]) -> Iterator[dict]:
    """The samples ``spans`` (from ``index_shard(path)``) as {"__key__", "__url__", suffix: bytes}."""
    with open(path, "rb") as f:
        for span in spans:
            f.seek(span.start)
            buf = f.read(span.end - span.start)
            if len(buf) < span.end - span.start:
                raise _cut_off()
            sample = {"__key__": span.key, "__url__": str(path)}
            for suffix, offset, size in span.members:
                if suffix in sample:
                    raise ValueError(f"{span.key}.{suffix}: duplicate member name in the sample")
                at = offset - span.start
                sample[suffix] = buf[at : at + size]
            yield sample
