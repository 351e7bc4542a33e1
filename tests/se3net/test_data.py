import dataclasses

import numpy as np
import pytest
import torch

from scenarios import load_scenario
from se3net.data import IMAGE_KEYS, PAPER_NOISE, PushDataset
from sim import PushWorld
from sim.dataset import DataConfig, generate
from sim.datastore import split_of
from sim.explore import ExplorationPolicy
from sim.shards import DataError

CFG = DataConfig("tiny", episodes=21, steps_per_episode=6, episodes_per_shard=7)


@pytest.fixture(scope="module")
def root(tmp_path_factory):
    root = tmp_path_factory.mktemp("data")
    generate(CFG, root, progress=False)
    return root


def test_splits_never_share_an_episode(root):
    seen = {}
    for split in ("train", "val", "test"):
        ds = PushDataset(root, split=split)
        episodes = {int(e) for e in ds.episode_index}
        assert all(split_of(e) == split for e in episodes)
        seen[split] = episodes
    assert seen["val"] == {18} and seen["test"] == {19}
    assert not (seen["train"] & seen["val"]) and not (seen["train"] & seen["test"])
    assert len(seen["train"]) == 19


def test_split_all_is_every_episode_of_train_val_and_test(root):
    parts = [PushDataset(root, split=s) for s in ("train", "val", "test")]
    every = PushDataset(root, split="all")
    assert sorted(int(e) for e in every.episode_index) == sorted(
        int(e) for ds in parts for e in ds.episode_index
    )
    assert sorted(int(e) for e in every.episode_index) == list(range(21))
    assert len(every) == sum(len(ds) for ds in parts)


def _fresh_observations(episode: int):
    """Simulate an episode afresh with the stored actions."""
    s = load_scenario("tiny")
    world = PushWorld(s)
    rng = np.random.default_rng([CFG.seed, episode])
    obs = world.reset(rng)
    policy = ExplorationPolicy(s, world.objects, rng, CFG.exploration)
    obs = [world.teleport_pusher(policy.start_position(obs))]
    return world, obs, policy


@pytest.mark.parametrize("horizon", [1, 3])
def test_targets_from_stored_associations_equal_a_fresh_simulation(root, horizon):
    ds = PushDataset(root, split="train", horizon=horizon)
    e_row = 2
    episode = int(ds.episode_index[e_row])
    world, obs, _ = _fresh_observations(episode)
    actions = ds.a["actions"][e_row]
    for a in actions[: int(ds.a["length"][e_row])]:
        obs.append(world.step(a))
    items = [i for i, (e, _) in enumerate(ds.items) if e == e_row]
    checked = 0
    for i in items:
        item = ds[i]
        t = item["t"]
        np.testing.assert_allclose(item["points"].numpy(), obs[t].points_cam, atol=2.5e-4)
        for k in range(1, horizon + 1):
            exact = world.targets(obs[t], obs[t + k])
            err = np.abs(item["target"][k - 1].numpy() - exact)[:, obs[t].valid]
            assert err.max() < 2.5e-4  # float16 body-frame points: well under 1 mm
            checked += 1
        np.testing.assert_array_equal(item["valid"].numpy(), obs[t].valid)
        np.testing.assert_array_equal(item["part"].numpy(), obs[t].part)
        u = item["u"].numpy()
        np.testing.assert_allclose(u[:, :2], actions[t : t + horizon], atol=1e-6)
        np.testing.assert_allclose(u[0, 2:], obs[t].pusher_xy_m, atol=1e-6)
    assert checked > 0


def test_target_validity_marks_points_that_stay_visible(root):
    ds = PushDataset(root, split="train", horizon=2)
    frac = np.mean(
        [
            ds[i]["target_valid"].float().mean().item() / ds[i]["valid"].float().mean().item()
            for i in range(0, len(ds), 7)
        ]
    )
    assert 0.9 < frac <= 1.0
    item = ds[0]
    assert not (item["target_valid"] & ~item["valid"]).any()


def test_noise_is_off_by_default_and_does_what_it_says(root):
    noise0 = load_scenario("tiny").noise
    assert noise0.depth_sd_m == 0 and noise0.assoc_window == 0
    clean = PushDataset(root, split="train")
    off = PushDataset(root, split="train", noise=noise0)
    i = 5
    for k in ("points", "target", "target_valid"):
        assert torch.equal(clean[i][k], off[i][k])

    sd = 0.01
    plain = PushDataset(root, split="train", noise=dataclasses.replace(noise0, depth_sd_m=sd))
    dz = np.concatenate(
        [
            (plain[j]["points"][2] - clean[j]["points"][2])[clean[j]["valid"]].numpy()
            for j in range(10)
        ]
    )
    assert abs(dz.std() / sd - 1) < 0.1 and abs(dz.mean()) < 0.1 * sd
    scaled = PushDataset(
        root, split="train", noise=dataclasses.replace(noise0, depth_sd_m=sd, depth_sd_scaled=True)
    )
    z = np.concatenate([clean[j]["points"][2][clean[j]["valid"]].numpy() for j in range(10)])
    dz2 = np.concatenate(
        [
            (scaled[j]["points"][2] - clean[j]["points"][2])[clean[j]["valid"]].numpy()
            for j in range(10)
        ]
    )
    assert abs((dz2 / z).std() / sd - 1) < 0.1
    # noise moves points along their rays: x/z and y/z are unchanged
    np.testing.assert_allclose(
        (plain[i]["points"][:2] / plain[i]["points"][2:].clamp(min=1e-9))[:, clean[i]["valid"]],
        (clean[i]["points"][:2] / clean[i]["points"][2:].clamp(min=1e-9))[:, clean[i]["valid"]],
        atol=1e-5,
    )
    assert not torch.equal(
        plain[i]["points"], PushDataset(root, split="train", noise=plain.noise, seed=1)[i]["points"]
    )

    m, thr = 5, 0.02
    assoc = PushDataset(
        root,
        split="train",
        noise=dataclasses.replace(noise0, assoc_window=m, assoc_depth_threshold_m=thr),
    )
    c, a = clean[i], assoc[i]
    tc, ta = c["target"][0].numpy(), a["target"][0].numpy()
    z = c["points"][2].numpy()
    H, W = z.shape
    changed = 0
    for v in range(H):
        for u in range(W):
            if not c["valid"][v, u]:
                continue
            rows, cols = range(max(0, v - 2), min(H, v + 3)), range(max(0, u - 2), min(W, u + 3))
            window = [
                (v2, u2)
                for v2 in rows
                for u2 in cols
                if c["valid"][v2, u2] and abs(z[v2, u2] - z[v, u]) <= thr + 1e-6
            ]
            assert any(np.allclose(ta[:, v, u], tc[:, v2, u2]) for v2, u2 in window)
            changed += not np.allclose(ta[:, v, u], tc[:, v, u])
    assert changed > 0.3 * c["valid"].sum().item()


def test_bad_reads_are_refused_with_what_to_do(root, tmp_path):
    with pytest.raises(DataError, match="horizon 7 does not fit episodes of 6 steps"):
        PushDataset(root, horizon=7)
    with pytest.raises(DataError, match="not a dataset folder"):
        PushDataset(tmp_path)
    with pytest.raises(ValueError, match="unknown split"):
        PushDataset(root, split="training")
    import shutil

    copy = tmp_path / "copy"
    shutil.copytree(root, copy)
    shard = copy / "shard_00001.npz"
    shard.write_bytes(shard.read_bytes()[:1000])
    with pytest.raises(
        DataError, match=r"shard_00001\.npz fails its checksum.*run the same `se3push data`"
    ):
        PushDataset(copy)
    with pytest.raises(DataError, match=r"shard_00001\.npz cannot be read"):
        PushDataset(copy, verify=False)


def test_a_strided_dataset_gives_every_other_pixel_with_its_full_resolution_targets(root):
    """A planning-resolution model's data: pixels keep their identity, so each kept pixel's
    targets and visibility are those judged at the camera's resolution."""
    full = PushDataset(root, split="train", horizon=2)
    half = PushDataset(root, split="train", horizon=2, stride=2)
    idx = list(range(0, len(full), 7))
    b, h = full.batch(idx), half.batch(idx)
    for key in IMAGE_KEYS:
        assert h[key].shape[-2:] == (16, 16)
        assert torch.equal(h[key], b[key][..., ::2, ::2])
    assert h["target_valid"].any() and (h["target"] != h["points"][:, None]).any()
    for key in ("u", "episode", "t"):
        assert torch.equal(h[key], b[key])
    with pytest.raises(DataError, match="stride 3 does not divide the 32x32 images"):
        PushDataset(root, stride=3)


def test_pooled_datasets_must_share_episode_length(tiny_data, tmp_path):
    other = tmp_path / "short"
    generate(DataConfig("tiny", episodes=2, steps_per_episode=4), other, progress=False)
    with pytest.raises(DataError, match="differ in steps_per_episode"):
        PushDataset([tiny_data, other])
    twice = PushDataset([tiny_data, tiny_data], split="train")
    assert len(twice) == 2 * len(PushDataset(tiny_data, split="train"))


def test_data_of_other_objects_pools_when_camera_and_actions_agree(tiny_data, tmp_path):
    """A generalist trains on several scenarios' data: what must agree is what the network
    sees and how actions act, not the objects."""
    for name in ("single_box", "household"):
        generate(DataConfig(name, episodes=2, steps_per_episode=8), tmp_path / name,
                 progress=False)  # fmt: skip
    both = PushDataset([tmp_path / "single_box", tmp_path / "household"], split="all")
    assert len(both) == 2 * 2 * 8
    with pytest.raises(DataError, match="other cameras or actions .*camera.width"):
        PushDataset([tmp_path / "single_box", tiny_data])


@pytest.mark.parametrize("noise", ["depth-scaled", "assoc-9"])
def test_an_items_noise_does_not_depend_on_the_batch_it_is_drawn_in(root, noise):
    ds = PushDataset(root, split="train", noise=PAPER_NOISE[noise], seed=3)
    alone = ds.batch([7])
    among = ds.batch([2, 7, 11])
    for k in ("points", "target", "target_valid"):
        assert torch.equal(alone[k][0], among[k][1])
    clean = PushDataset(root, split="train").batch([7])
    changed = "points" if noise.startswith("depth") else "target"
    assert not torch.equal(alone[changed], clean[changed])
    ds.set_epoch(1)  # a fresh draw in the next pass over the data
    assert not torch.equal(ds.batch([7])[changed], alone[changed])


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_a_batch_assembled_on_the_gpu_is_the_cpus(root):
    idx = [0, 5, 9]
    cpu = PushDataset(root, split="train", horizon=2).batch(idx)
    gpu = PushDataset(root, split="train", horizon=2, device="cuda").batch(idx)
    for k, v in cpu.items():
        assert gpu[k].device.type == "cuda"
        torch.testing.assert_close(gpu[k].cpu(), v, atol=1e-6, rtol=0)


@pytest.mark.parametrize("noise", ["depth", "assoc-9"])
def test_under_noise_the_moving_points_are_the_ones_that_truly_move(root, noise):
    """The paper's metric averages over the points whose true flow is non-zero. Under depth
    noise nearly every noisy point differs from its noisy target, so judged from them nearly
    every point would move; judged from the batch's noise-free flow, the moving points are the
    clean data's (among those whose target stays visible), and the no-motion baseline and the
    loss are taken over them."""
    from se3net.metrics import FlowStats, moving_points, point_loss, true_flow

    idx = list(range(0, len(PushDataset(root, split="train")), 3))
    clean = PushDataset(root, split="train").batch(idx)
    noisy = PushDataset(root, split="train", noise=PAPER_NOISE[noise]).batch(idx)
    assert torch.equal(noisy["true_flow_m"], clean["true_flow_m"])

    def moving(b, truth):
        return moving_points(b["points"], b["target"][:, 0], b["target_valid"][:, 0], truth)

    truly = moving(clean, true_flow(clean, 0))
    assert torch.equal(truly, moving(clean, None))  # without noise the two agree
    judged = moving(noisy, true_flow(noisy, 0))
    seen_or_not = {**clean, "target_valid": torch.ones_like(clean["target_valid"])}
    assert not (judged & ~moving(seen_or_not, None)).any()  # every one of them truly moves
    assert judged.sum() >= 0.9 * truly.sum() > 0
    if noise == "depth":
        assert moving(noisy, None).sum() > 5 * truly.sum()  # what the noisy flow would say
    stats = FlowStats()
    stats.add(noisy["points"], noisy["points"], noisy["target"][:, 0],
              noisy["target_valid"][:, 0], true_flow(noisy, 0))  # fmt: skip
    assert stats.n == judged.sum()
    # a prediction of the noisy targets on the moving points costs nothing, whatever the rest
    off = noisy["target"][:, 0] + 0.05 * (~judged)[:, None]
    loss = point_loss(off, noisy["target"][:, 0], judged, noisy["points"],
                      true_flow_m=true_flow(noisy, 0))  # fmt: skip
    assert float(loss) == 0.0
