from pathlib import Path

import numpy as np
import pytest

import sim.dataset as dataset
from scenarios import InputError, ScenarioError, load_scenario
from sim import PushWorld
from sim.dataset import DataConfig, generate
from sim.datastore import read_manifest, split_of, summarize
from sim.explore import ExplorationPolicy
from sim.shards import DataError

CFG = DataConfig("tiny", episodes=5, steps_per_episode=6, episodes_per_shard=2)


def shard_bytes(root: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(root.glob("shard_*.npz"))}


@pytest.fixture(scope="module")
def reference(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("ref")
    generate(CFG, root, progress=False)
    return root


def test_tiny_generation_writes_complete_manifest(reference):
    m = read_manifest(reference)
    assert m["complete"] and len(m["shards"]) == 3
    st = summarize(m)
    assert st["episodes"] == 5 and 0 < st["examples"] <= 30
    assert st["qp_failures"] == 0
    assert sum(st["mode_fractions"].values()) == pytest.approx(1.0)
    assert m["identity"]["exploration"]["p_aimed"] == CFG.exploration.p_aimed


def test_two_workers_give_the_same_bytes(reference, tmp_path):
    generate(CFG, tmp_path, workers=2, progress=False)
    assert shard_bytes(tmp_path) == shard_bytes(reference)


def _interrupt_after_one_shard(monkeypatch):
    """Make ``generate`` stop (KeyboardInterrupt) once one shard is written; returns the real
    ``make_shard`` to put back."""
    real = dataset.make_shard
    calls = []

    def interrupted(cfg, i, out_dir, scenario):
        if calls:
            raise KeyboardInterrupt
        calls.append(i)
        return real(cfg, i, out_dir, scenario)

    monkeypatch.setattr(dataset, "make_shard", interrupted)
    return real


def test_interrupted_run_resumes_to_the_same_bytes(reference, tmp_path, monkeypatch):
    real = _interrupt_after_one_shard(monkeypatch)
    with pytest.raises(KeyboardInterrupt):
        generate(CFG, tmp_path, progress=False)
    first = shard_bytes(tmp_path)
    assert len(first) == 1
    (tmp_path / ".shard_00001.npz.tmp-999").write_bytes(b"half a shard")  # a crash mid-write
    with pytest.raises(DataError, match="incomplete"):
        read_manifest(tmp_path)
    monkeypatch.setattr(dataset, "make_shard", real)
    mtime = (tmp_path / "shard_00000.npz").stat().st_mtime_ns
    generate(CFG, tmp_path, progress=False)
    assert shard_bytes(tmp_path) == shard_bytes(reference)
    assert (tmp_path / "shard_00000.npz").stat().st_mtime_ns == mtime  # not rewritten
    assert not list(tmp_path.glob(".shard_*"))


def test_a_repair_of_damaged_shards_leaves_the_folder_incomplete_until_it_ends(
    reference, tmp_path, monkeypatch
):
    """Shards damaged after a complete run are made again; a repair interrupted half-way
    leaves a folder that readers refuse (not one that reads as complete with a shard
    missing), and finishing it gives the reference's bytes."""
    generate(CFG, tmp_path, progress=False)
    for name in ("shard_00000.npz", "shard_00001.npz"):
        (tmp_path / name).write_bytes(b"damaged")
    real = _interrupt_after_one_shard(monkeypatch)
    with pytest.raises(KeyboardInterrupt):
        generate(CFG, tmp_path, progress=False)
    with pytest.raises(DataError, match="incomplete"):
        read_manifest(tmp_path)
    monkeypatch.setattr(dataset, "make_shard", real)
    generate(CFG, tmp_path, progress=False)
    assert read_manifest(tmp_path)["complete"]
    assert shard_bytes(tmp_path) == shard_bytes(reference)


def test_a_folder_whose_manifest_is_not_a_datasets_is_refused(tmp_path):
    (tmp_path / "manifest.json").write_text('{"name": "my notes"}')
    with pytest.raises(DataError, match="is not a dataset manifest"):
        read_manifest(tmp_path)


def test_episode_depends_only_on_seed_and_index():
    s = load_scenario("tiny")
    a = dataset.run_episode(s, CFG, 3)
    b = dataset.run_episode(s, CFG, 3)
    for k in a:
        np.testing.assert_array_equal(a[k], b[k])
    c = dataset.run_episode(s, CFG, 4)
    assert not np.array_equal(a["actions"], c["actions"])


def test_split_is_by_episode_and_covers_everything():
    splits = [split_of(e) for e in range(200)]
    assert splits.count("train") == 180 and splits.count("val") == 10 and splits.count("test") == 10


def test_folder_with_other_data_is_refused(reference, tmp_path):
    generate(CFG, tmp_path, progress=False)
    with pytest.raises(
        DataError, match=r"different dataset.*seed: folder has 0, this run asks for 1"
    ):
        generate(
            DataConfig("tiny", episodes=5, steps_per_episode=6, episodes_per_shard=2, seed=1),
            tmp_path,
            progress=False,
        )
    with pytest.raises(DataError, match=r"scenario\.name: folder has 'tiny'"):
        generate(
            DataConfig("single_box", episodes=5, steps_per_episode=6, episodes_per_shard=2),
            tmp_path,
            progress=False,
        )


def test_non_dataset_folder_and_unwritable_folder_are_refused(tmp_path):
    (tmp_path / "notes.txt").write_text("mine")
    with pytest.raises(DataError, match="not empty and holds no dataset"):
        generate(CFG, tmp_path, progress=False)
    with pytest.raises(PermissionError, match="cannot write to"):
        generate(CFG, tmp_path / "notes.txt" / "data", progress=False)


def test_unknown_scenario_and_bad_counts_are_refused(tmp_path):
    with pytest.raises(ScenarioError, match="unknown scenario"):
        generate(DataConfig("nope", episodes=1), tmp_path, progress=False)
    with pytest.raises(InputError, match="episodes must be a positive integer"):
        DataConfig("tiny", episodes=0)
    with pytest.raises(InputError, match="--workers must be at least 1"):
        generate(DataConfig("tiny", episodes=1), tmp_path, workers=0, progress=False)


def test_stored_episode_replays_to_the_same_world(reference):
    """Stored actions, replayed from the same seed, retrace the stored poses exactly."""
    s = load_scenario("tiny")
    ep = dataset.run_episode(s, CFG, 2)
    world = PushWorld(s)
    rng = np.random.default_rng([CFG.seed, 2])
    obs = world.reset(rng)
    obs = world.teleport_pusher(
        ExplorationPolicy(s, world.objects, rng, CFG.exploration).start_position(obs)
    )
    for t in range(int(ep["length"])):
        obs = world.step(ep["actions"][t])
        np.testing.assert_array_equal(
            obs.T_world_part, ep["T_world_part"][t + 1, : len(obs.T_world_part)]
        )


def test_a_scenario_file_edited_during_a_run_does_not_change_its_data(tmp_path, monkeypatch):
    """The workers make every shard from the scenario the folder's identity was made from,
    not from the file read again (which would record the new data under the old identity)."""
    import dataclasses
    from importlib import resources

    toml = tmp_path / "mine.toml"
    text = (resources.files("scenarios") / "tiny.toml").read_text()  # the table's friction 0.5
    toml.write_text(text)
    cfg = dataclasses.replace(CFG, scenario=str(toml))
    generate(cfg, tmp_path / "clean", progress=False)
    real = dataset.make_shard

    def then_edited(cfg, i, out_dir, scenario):
        out = real(cfg, i, out_dir, scenario)
        toml.write_text(text.replace("friction = 0.5", "friction = 0.9", 1))
        return out

    toml.write_text(text)
    monkeypatch.setattr(dataset, "make_shard", then_edited)
    generate(cfg, tmp_path / "edited", progress=False)
    assert "friction = 0.9" in toml.read_text()
    assert shard_bytes(tmp_path / "edited") == shard_bytes(tmp_path / "clean")
