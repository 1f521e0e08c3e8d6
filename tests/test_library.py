import numpy as np
import pytest

from rba.data.library import LibraryNotFoundError, SkillLibrary, build_all, generate


def test_generate_is_seeded_and_ids_are_split_prefixed():
    a = generate("toy", "serve", 12, seed=3, workers=1, progress=False)
    b = generate("toy", "serve", 12, seed=3, workers=1, progress=False)
    assert a.version == b.version
    assert a.ids[0] == "serve-00000" and len(a) == 12
    assert generate("toy", "serve", 12, seed=4, workers=1, progress=False).version != a.version


def test_save_load_roundtrip(tmp_path):
    lib = generate("toy", "train", 10, seed=0, workers=1, progress=False)
    lib.save(tmp_path)
    back = SkillLibrary.load("toy", "train", tmp_path)
    assert back.ids == lib.ids and back.version == lib.version
    np.testing.assert_array_equal(back.trajectory(3), lib.trajectory(3))
    r = back.rollout(back.index_of("train-00004"))
    assert r.proxies == lib.proxies_of(4) and r.states.shape == (24, 4)


def test_tampered_arrays_are_refused(tmp_path):
    lib = generate("toy", "train", 5, seed=0, workers=1, progress=False)
    other = generate("toy", "train", 5, seed=1, workers=1, progress=False)
    lib.save(tmp_path)
    other_dir = tmp_path / "other"
    other.save(other_dir)
    (other_dir / "toy" / "train.npz").replace(tmp_path / "toy" / "train.npz")
    with pytest.raises(ValueError, match="does not match its metadata"):
        SkillLibrary.load("toy", "train", tmp_path)


def test_missing_library_names_the_fix(tmp_path):
    with pytest.raises(LibraryNotFoundError, match="rba build toy"):
        SkillLibrary.load("toy", "serve", tmp_path)
    with pytest.raises(ValueError, match="valid: train, serve, val, test"):
        SkillLibrary.load("toy", "nope", tmp_path)


def test_build_all_keeps_test_params_out_of_train(tmp_path):
    libs = build_all("toy", seed=1, sizes={"train": 15, "serve": 15, "val": 10, "test": 10}, workers=1, root=tmp_path,
                     progress=False)
    train = {tuple(p) for p in libs["train"].params}
    assert not any(tuple(p) in train for p in libs["test"].params)
    assert (tmp_path / "toy" / "test.json").exists()


def test_parallel_generation_matches_serial():
    serial = generate("toy", "test", 8, seed=2, workers=1, progress=False)
    parallel = generate("toy", "test", 8, seed=2, workers=2, progress=False)
    assert serial.version == parallel.version
