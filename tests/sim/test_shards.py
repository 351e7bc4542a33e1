from pathlib import Path

from sim.shards import portable_path


def test_paths_under_the_cwd_are_recorded_relative_to_it(tmp_path, monkeypatch):
    (tmp_path / "work" / "runs").mkdir(parents=True)
    monkeypatch.chdir(tmp_path / "work")
    assert portable_path(tmp_path / "work" / "runs" / "a" / "best.pt") == "runs/a/best.pt"
    assert portable_path(str(tmp_path / "work" / "runs" / ".." / "data")) == "data"
    assert portable_path("runs/a/best.pt") == "runs/a/best.pt"  # relative: as given
    assert portable_path("default") == "default"
    elsewhere = tmp_path / "elsewhere" / "best.pt"
    assert portable_path(elsewhere) == str(elsewhere)  # not under the cwd: as given
    assert portable_path("../x.pt") == str(Path("../x.pt"))


def test_a_damaged_shard_read_without_its_checksum_is_refused_in_one_line(tmp_path):
    """Bytes flipped across a compressed shard: every read either succeeds or raises DataError
    (zlib's own error among them), never another exception."""
    import numpy as np

    from sim.shards import DataError, read_shard, write_shard

    path = tmp_path / "s.npz"
    rng = np.random.default_rng(0)
    write_shard(path, {"a": rng.normal(size=(200, 200)), "b": np.arange(100_000)})
    data = path.read_bytes()
    refused = 0
    for pos in range(100, len(data) - 400, 997):
        damaged = bytearray(data)
        damaged[pos] ^= 0xFF
        (tmp_path / "d.npz").write_bytes(bytes(damaged))
        try:
            read_shard(tmp_path / "d.npz")
        except DataError:
            refused += 1
    assert refused > 100
