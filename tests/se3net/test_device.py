import pytest
import torch

from scenarios import InputError
from se3net.checkpoint import load_checkpoint
from se3net.device import check_device


def test_cpu_is_a_device_everywhere():
    assert check_device("cpu") == torch.device("cpu")
    assert check_device(torch.device("cpu")) == torch.device("cpu")


@pytest.mark.parametrize("name", ["gpu7", "nonsense", "", "cuda:-1", "meta"])
def test_names_torch_rejects_or_that_are_no_compute_device_are_refused(name):
    with pytest.raises(InputError, match="use cpu"):
        check_device(name)


def test_cuda_without_cuda_says_so(monkeypatch):
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    with pytest.raises(InputError, match="CUDA is not available on this machine.*use cpu"):
        check_device("cuda")


def test_a_cuda_index_beyond_the_devices_names_the_ones_there(monkeypatch):
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    monkeypatch.setattr(torch.cuda, "device_count", lambda: 2)
    assert check_device("cuda:1") == torch.device("cuda:1")
    with pytest.raises(InputError, match=r"has 2 CUDA device\(s\); use cuda:0 to cuda:1"):
        check_device("cuda:9")


def test_mps_without_mps_says_so(monkeypatch):
    monkeypatch.setattr(torch.backends.mps, "is_available", lambda: False)
    with pytest.raises(InputError, match="MPS is not available"):
        check_device("mps")


def test_loading_a_checkpoint_onto_a_missing_device_is_refused(monkeypatch):
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    with pytest.raises(InputError, match="CUDA is not available"):
        load_checkpoint("default", device="cuda")
