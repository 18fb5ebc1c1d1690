"""The commands that render their own sequences into a --work cache (denoise.train,
denoise.validate, denoise.fit) take the export's cluster flags and render every
missing sequence in one export."""
from __future__ import annotations

import importlib
import json
from pathlib import Path

import pytest

from tests.test_validate import tiny_spec

COMMANDS = ["denoise.train", "denoise.validate", "denoise.fit"]


@pytest.mark.parametrize("command", COMMANDS)
@pytest.mark.parametrize("flags, words", [
    (["--workers", "0"], "--workers: expected 1..1024, found 0"),
    (["--scheduler", "no host"], "--scheduler 'no host': expected tcp://HOST:PORT or HOST:PORT"),
    (["--local", "--workers", "2"], "argument --workers: not allowed with argument --local"),
])
def test_a_bad_cluster_flag_is_one_line_before_any_render(command, flags, words, tmp_path, capsys):
    main = importlib.import_module(command).main
    argv = [str(tiny_spec(tmp_path, 5)), "--work", str(tmp_path / "work"), *flags]
    if command != "denoise.validate":
        argv += ["--out", str(tmp_path / "out.json")]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and words in err, err
    assert not (tmp_path / "work").exists() and not (tmp_path / "out.json").exists()


def test_the_sequences_render_in_one_export_on_the_workers_given_with_the_bytes_of_one_process(tmp_path, capsys):
    """denoise.validate --workers 2 renders both sequences on one LocalCluster of 2
    workers (its manifest in --work says so) into the bytes a --local run writes."""
    from denoise.validate import main

    specs = [str(tiny_spec(tmp_path, 5)), str(tiny_spec(tmp_path, 6))]
    common = ["--reference-spp", "2", "--methods", "bilateral"]
    assert main([*specs, "--work", str(tmp_path / "dask"), "--workers", "2", *common]) == 0
    assert main([*specs, "--work", str(tmp_path / "here"), "--local", *common]) == 0
    capsys.readouterr()
    manifest = json.loads((tmp_path / "dask" / "dataset.json").read_text())
    assert manifest["runner"] == "dask" and manifest["workers"] == 2, manifest
    assert sorted(s["name"] for s in manifest["sequences"]) == ["tiny5", "tiny6"]
    assert json.loads((tmp_path / "here" / "dataset.json").read_text())["runner"] == "local"
    files = sorted(p.relative_to(tmp_path / "here") for p in (tmp_path / "here").rglob("*_[0-9]*.*"))
    assert len(files) == (5 + 6) * (7 + 3)  # per frame: beauty, 5 G-buffers, the camera; the truth and its halves
    for name in files:
        assert (tmp_path / "dask" / name).read_bytes() == (tmp_path / "here" / name).read_bytes(), name
    # a rerun renders nothing, so starts no cluster
    assert main([*specs, "--work", str(tmp_path / "dask"), "--workers", "2", *common]) == 0
    assert json.loads((tmp_path / "dask" / "dataset.json").read_text())["runner"] == "local"


def test_one_export_needs_its_folders_in_one_work(tmp_path):
    from denoise.validate import render
    from export import Spec

    spec = Spec.load(Path(tiny_spec(tmp_path, 5)))
    with pytest.raises(ValueError, match="not in one --work"):
        render([(spec, tmp_path / "a" / "x"), (spec, tmp_path / "b" / "y")])


@pytest.mark.parametrize("command", COMMANDS)
def test_a_sequence_whose_frames_are_another_ones_truth_is_refused_before_any_render(command, tmp_path, capsys):
    """Specs x and x_reference in one --work: x_reference's frames would be x's truth."""
    main = importlib.import_module(command).main
    spec = tiny_spec(tmp_path, 5)
    other = tmp_path / f"{spec.stem}_reference.json"
    other.write_text(spec.read_text())
    argv = [str(spec), str(other), "--work", str(tmp_path / "work"), "--local"]
    if command != "denoise.validate":
        argv += ["--out", str(tmp_path / "out.json")]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "would be both tiny5's ground truth and tiny5_reference's frame folder" in err, err
    assert not (tmp_path / "work").exists()


@pytest.mark.parametrize("command, name, words", [
    ("denoise.validate", ".", "a sequence named '.' has no folder of its own in --work"),
    ("denoise.fit", "..", "a sequence named '..' has no folder of its own in --work"),
    ("denoise.train", ".", "a sequence named '.' has no folder of its own in --work"),
    ("denoise.validate", "dataset.json", "a sequence's folder would be the file the command writes there"),
    ("denoise.train", "out.checkpoint.npz", "a sequence's folder would be the file the command writes there"),
])
def test_a_spec_whose_folder_is_not_its_own_is_refused_before_any_render(command, name, words, tmp_path, capsys):
    """A spec named "..json" rendered into --work itself (its truth beside it), "...json" into
    --work's parent; one named as the manifest or the checkpoint was refused after the render."""
    main = importlib.import_module(command).main
    spec = tmp_path / "specs" / f"{name}.json"
    spec.parent.mkdir()
    spec.write_text(tiny_spec(tmp_path, 5).read_text())
    argv = [str(spec), "--work", str(tmp_path / "a" / "work"), "--local"]
    if command != "denoise.validate":
        argv += ["--out", str(tmp_path / "out.json")]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and words in err, err
    assert sorted(p.name for p in tmp_path.rglob("*")) == sorted(["specs", f"{name}.json", "tiny5.json"])


def test_a_folder_where_the_manifest_goes_is_refused_before_any_render(tmp_path, capsys):
    from denoise.validate import main

    (tmp_path / "work" / "dataset.json").mkdir(parents=True)
    assert main([str(tiny_spec(tmp_path, 5)), "--work", str(tmp_path / "work"), "--local"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "dataset.json: a folder where the command writes a file" in err, err
    assert [p.name for p in (tmp_path / "work").iterdir()] == ["dataset.json"]
