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
