"""Determinism, sharding, chunk files, the Dataset and the CLI of ``footmesh synth``."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from footmesh.cli import main
from footmesh.synth import dataset as ds
from footmesh.synth.render import Renderer
from footmesh.synth.scene import SynthConfig, thesis_view, view_config

CONFIG = SynthConfig(size=48)


def test_same_seed_and_index_give_identical_bytes(renderer):
    a, b = renderer.render(3, 11), renderer.render(3, 11)
    assert a.keys() == b.keys()
    for key in a:
        assert np.asarray(a[key]).tobytes() == np.asarray(b[key]).tobytes(), key
    c = renderer.render(3, 12)
    assert a["rgb"].tobytes() != c["rgb"].tobytes()


def test_a_sample_is_the_same_whatever_threads_torch_was_given():
    # guided seed 4243 samples 4 and 13 are IK poses whose toe chains took other solutions on two threads
    renderer = Renderer(view_config("guided", size=48, reference="a4"))
    before = torch.get_num_threads()
    try:
        torch.set_num_threads(1)
        one = [renderer.render(4243, i) for i in (4, 13)]
        torch.set_num_threads(2)
        two = [renderer.render(4243, i) for i in (4, 13)]
        assert torch.get_num_threads() == 2  # the caller's setting is given back
    finally:
        torch.set_num_threads(before)
    for a, b in zip(one, two, strict=True):
        np.testing.assert_array_equal(a["angles"], b["angles"])
        assert a["rgb"].tobytes() == b["rgb"].tobytes()


def test_shards_partition_the_chunks():
    for n, k in ((1, 1), (1000, 3), (513, 2), (2000, 7)):
        got = sorted(c for i in range(k) for c in ds.shard_chunks(n, k, i))
        assert got == list(range(-(-n // ds.CHUNK)))
        indices = [i for c in got for i in ds.chunk_indices(c, n)]
        assert indices == list(range(n))
    with pytest.raises(ValueError):
        ds.shard_chunks(10, 2, 2)


def test_files_do_not_depend_on_the_shard_count(tmp_path):
    one, two = tmp_path / "one", tmp_path / "two"
    ds.generate(one, 5, seed=1, config=CONFIG, progress=False, chunk=2, threads=1)
    for i in range(2):  # and rendered by three threads each
        ds.generate(two, 5, seed=1, config=CONFIG, shards=2, shard_index=i, progress=False, chunk=2, threads=3)
    names = sorted(p.name for p in one.iterdir())
    assert (
        names
        == sorted(p.name for p in two.iterdir())
        == ["chunk-000000.npz", "chunk-000001.npz", "chunk-000002.npz", "meta.json"]
    )
    for name in names:
        assert (one / name).read_bytes() == (two / name).read_bytes(), name
    # resumable: a rerun writes nothing; other settings in the same folder are refused
    assert ds.generate(one, 5, seed=1, config=CONFIG, progress=False, chunk=2) == []
    with pytest.raises(ValueError, match="other settings"):
        ds.generate(one, 5, seed=2, config=CONFIG, progress=False, chunk=2)


def test_dataset_random_access(tmp_path):
    from footmesh.synth.render import Renderer

    ds.generate(tmp_path, 5, seed=4, config=CONFIG, progress=False, chunk=2)
    data = ds.SynthDataset(tmp_path)
    assert len(data) == 5 and list(data.indices) == [0, 1, 2, 3, 4]
    want = Renderer(CONFIG).render(4, 3)
    got = data[3]
    assert got.keys() == want.keys()
    for key in want:
        np.testing.assert_array_equal(got[key], want[key])
    assert data[-1]["index"] == 4
    with pytest.raises(IndexError):
        data[5]
    import torch.utils.data

    assert isinstance(data, torch.utils.data.Dataset)


def test_thesis_views_are_22_distinct_and_toes_face_the_camera_at_270_about_x():
    dirs = np.array([thesis_view(i, "left")[0] for i in range(22)])
    assert len({tuple(np.round(d, 6)) for d in dirs}) == 22
    d, _, axis, deg = thesis_view(9, "left")
    assert (axis, deg) == ("X", 270)
    np.testing.assert_allclose(d, [1, 0, 0], atol=1e-12)  # in front of the toes
    np.testing.assert_allclose(thesis_view(0, "left")[0], [0, 0, 1], atol=1e-12)  # from above


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--out", "x", "--n", "0"], "--n must be"),
        (["--out", "x", "--n", "4", "--shards", "2", "--shard-index", "2"], "--shard-index"),
        (["--out", "x.jpg", "--preview", "4"], "must end in .png"),
        (["--out", "x", "--n", "4", "--size", "8"], "size must be"),
    ],
)
def test_bad_cli_arguments_give_one_line(argv, message, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(["synth", *argv]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1


def test_cli_preview_writes_a_sheet(tmp_path):
    out = tmp_path / "sheet.png"
    assert main(["synth", "--out", str(out), "--preview", "2", "--size", "48"]) == 0
    from PIL import Image

    assert Image.open(out).size[0] > 48


def test_a_dataset_made_before_a_config_field_existed_resumes(tmp_path):
    """A field added to ``SynthConfig`` later, at its default, renders what an older dataset was made with: its
    meta.json (without the field) still matches, and a non-default value is still refused."""
    import json

    ds.generate(tmp_path, 3, seed=1, config=CONFIG, progress=False, chunk=2)
    meta_path = tmp_path / "meta.json"
    meta = json.loads(meta_path.read_text())
    del meta["config"]["rgb_noise_sd"]
    meta_path.write_text(json.dumps(meta))
    assert ds.generate(tmp_path, 3, seed=1, config=CONFIG, progress=False, chunk=2) == []
    noisier = SynthConfig(size=48, rgb_noise_sd=0.02)
    with pytest.raises(ValueError, match="other settings"):
        ds.generate(tmp_path, 3, seed=1, config=noisier, progress=False, chunk=2)


def test_other_formats_are_read_or_refused_clearly(tmp_path):
    """A folder written by an older format is read (same keys, shapes, units) but not added to; an unknown one is
    refused by the reader."""
    import json

    ds.generate(tmp_path, 3, seed=1, config=CONFIG, progress=False, chunk=2)
    meta_path = tmp_path / "meta.json"
    meta = json.loads(meta_path.read_text())
    assert meta["format"] == ds.FORMAT
    meta_path.write_text(json.dumps({**meta, "format": "footmesh-synth-1"}))
    assert len(ds.SynthDataset(tmp_path)) == 3
    with pytest.raises(ValueError, match="format 'footmesh-synth-1'"):
        ds.generate(tmp_path, 3, seed=1, config=CONFIG, progress=False, chunk=2)
    meta_path.write_text(json.dumps({**meta, "format": "footmesh-synth-99"}))
    with pytest.raises(ValueError, match="not one this version reads"):
        ds.SynthDataset(tmp_path)
