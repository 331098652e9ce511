"""The loader's shard reader: webdataset's samples, only the slot's own bytes read, cut-off
shards refused."""

import sys
import tarfile
from pathlib import Path

import pytest
import webdataset as wds

sys.path.insert(0, str(Path(__file__).parent))
from fixtures_shards import write_fixture_shards  # noqa: E402

from train.data import DataSettings, ShardError, ShardStream, shard_urls  # noqa: E402
from train.shard_reader import index_shard, read_samples  # noqa: E402


@pytest.fixture(scope="module")
def shard(tmp_path_factory) -> Path:
    ds = write_fixture_shards(tmp_path_factory.mktemp("ds"), counts={"train": 6}, n_points=300, per_shard=6)
    return Path(shard_urls(ds, "knife", "train")[0])


def webdataset_samples(path: Path) -> list[dict]:
    stream = wds.WebDataset([str(path)], shardshuffle=False, nodesplitter=None, workersplitter=None, empty_check=False)
    return [{k: v for k, v in s.items() if k != "__local_path__"} for s in stream]


def test_samples_equal_webdatasets(shard):
    ours = list(read_samples(shard, index_shard(shard)))
    assert len(ours) == 6
    assert ours == webdataset_samples(shard)


def test_a_slot_reads_only_its_samples(shard, monkeypatch):
    spans = index_shard(shard)
    asked = []
    real_open = open

    class Counting:
        def __init__(self, f):
            self.f = f

        def seek(self, at):
            self.f.seek(at)

        def read(self, n):
            asked.append(n)
            return self.f.read(n)

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            self.f.close()

    monkeypatch.setattr("builtins.open", lambda p, m="r", *a, **k: Counting(real_open(p, m, *a, **k)))
    got = list(read_samples(shard, spans[1::3]))
    assert [s["__key__"] for s in got] == [spans[1].key, spans[4].key]
    assert sum(asked) == sum(s.end - s.start for s in spans[1::3])  # not the whole tar
    assert sum(asked) < 0.4 * shard.stat().st_size


def test_strided_slots_split_a_shard_without_overlap(shard):
    keys = []
    for rank in range(3):  # three slots, one shard: every third sample each
        stream = ShardStream([str(shard)], DataSettings(n_points=100, image_size=32), 0, True, rank, 3)
        it = iter(stream)
        keys.append({next(it)["key"] for _ in range(2)})
    assert all(len(k) == 2 for k in keys)
    assert len(keys[0] | keys[1] | keys[2]) == 6


@pytest.mark.parametrize("keep", [0.5, 0.3, 0.02])  # 0.5: between two members
def test_a_cut_off_shard_is_named(shard, tmp_path, keep):
    cut = tmp_path / "train-00000.tar"
    data = shard.read_bytes()
    cut.write_bytes(data[: int(len(data) * keep)])
    with pytest.raises(tarfile.ReadError, match="unexpected end of data"):
        index_shard(cut)
    stream = ShardStream([str(cut)], DataSettings(n_points=100, image_size=32), 0, False)
    with pytest.raises(ShardError, match=f"{cut}: unreadable shard \\(ReadError: unexpected end of data\\)"):
        list(stream)
