"""eval/checksums.py: the SHA-256 checksums an evaluation records of its predictions and ground truth."""
import hashlib

from eval.checksums import combined, file_sha256, files_sha256, scene_checksums, tree_files


def _scene(root, text="a"):
    (root / "test" / "000").mkdir(parents=True)
    (root / "test" / "000" / "albedo.png").write_bytes(text.encode())
    (root / "scene.json").write_text("{}")
    (root / "train").mkdir()
    (root / "train" / "x.png").write_bytes(b"not scored")
    return root


def test_file_checksum_is_sha256_of_the_bytes(tmp_path):
    (tmp_path / "f").write_bytes(b"abc")
    assert file_sha256(tmp_path / "f") == hashlib.sha256(b"abc").hexdigest()


def test_folder_checksum_is_of_relative_paths_and_contents(tmp_path):
    a, b = _scene(tmp_path / "a"), _scene(tmp_path / "b")
    sums = scene_checksums(a, b, "test")
    assert sums == scene_checksums(b, a, "test")  # where a folder lives does not matter
    line = f"test/000/albedo.png {hashlib.sha256(b'a').hexdigest()}"
    assert sums["predictions"] == hashlib.sha256(line.encode()).hexdigest()
    (b / "train" / "x.png").write_bytes(b"changed")  # another split is not part of it
    assert scene_checksums(a, b, "test") == sums
    (b / "test" / "000" / "albedo.png").write_bytes(b"b")  # one scored byte changes it
    assert scene_checksums(a, b, "test")["predictions"] != sums["predictions"]
    (b / "test" / "000" / "albedo.png").rename(b / "test" / "000" / "roughness.png")
    assert files_sha256(b, tree_files(b, ("test",))) != files_sha256(a, tree_files(a, ("test",)))


def test_combined_depends_on_every_scene_and_its_name(tmp_path):
    one = {"s1": {"ground_truth": "1", "predictions": "2"}, "s2": {"ground_truth": "3", "predictions": "4"}}
    assert combined(one) == combined(dict(reversed(list(one.items()))))
    assert combined(one)["predictions"] != combined({**one, "s2": {"ground_truth": "3", "predictions": "5"}})["predictions"]
    assert combined(one) != combined({"s3": one["s1"], "s2": one["s2"]})
