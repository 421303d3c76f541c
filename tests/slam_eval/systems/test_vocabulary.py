"""The DBoW2 vocabulary builder (``uss_slam.slam_eval.systems.orbslam3.vocabulary``) and ``uss-vocab``: clustering
rules, TF-IDF weights, the text format ORB-SLAM3 loads, the reader's checks, the CLI."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from uss_slam.core.errors import DataFormatError, UssSlamError
from uss_slam.slam_eval.systems.orbslam3 import vocabulary as voc
from uss_slam.slam_eval.systems.orbslam3.vocab_cli import main as vocab_main


def _random_sets(n_images: int = 6, per_image: int = 150, seed: int = 0) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    return [rng.integers(0, 256, (per_image, 32), dtype=np.uint8) for _ in range(n_images)]


def _depth(vocab: voc.Vocabulary, node: int) -> int:
    depth = 0
    while node != 0:
        node = int(vocab.parents[node - 1])
        depth += 1
    return depth


def test_tree_structure_follows_dbow2() -> None:
    vocab = voc.build_vocabulary(_random_sets(), k=5, levels=3, seed=1)
    n = vocab.n_nodes
    children = np.bincount(vocab.parents, minlength=n + 1)
    # parents are defined before their children; nodes are numbered as DBoW2 creates them
    assert all(0 <= p < node for node, p in enumerate(vocab.parents.tolist(), start=1))
    assert children.max() <= 5 and children[0] == 5
    # words are exactly the nodes without children, and no node is deeper than L
    assert np.array_equal(vocab.leaves, children[1:] == 0)
    assert max(_depth(vocab, node) for node in range(1, n + 1)) == 3
    assert n + 1 <= voc.max_nodes(5, 3)
    # 900 random descriptors fill the tree: 5 + 25 + 125 nodes
    assert n == 155 and vocab.n_words == 125
    # children of a node are consecutive ids (DBoW2 creates a level's nodes together)
    for parent in range(n + 1):
        kids = np.flatnonzero(vocab.parents == parent) + 1
        if len(kids):
            assert np.array_equal(kids, np.arange(kids[0], kids[0] + len(kids)))
    assert np.all(vocab.weights[~vocab.leaves] == 0)


def test_majority_rule_and_known_clusters() -> None:
    # FORB::meanValue: a bit is set when at least half of the members have it (ties set)
    a = np.zeros(32, np.uint8)
    b = np.full(32, 0xFF, np.uint8)
    assert np.array_equal(voc._majority(np.unpackbits(np.stack([a, b]), axis=1)), b)
    assert np.array_equal(voc._majority(np.unpackbits(np.stack([a, a, b]), axis=1)), a)
    # Two far-apart groups, k=2, L=1: two words whose descriptors are the groups' majorities.
    group_a = np.zeros((4, 32), np.uint8)
    group_a[0, 0] = 0b1000_0000  # one outlier bit: the majority drops it
    group_b = np.full((4, 32), 0xFF, np.uint8)
    group_b[1, 31] = 0xFE
    images = [group_a, np.concatenate([group_a[:2], group_b])]
    vocab = voc.build_vocabulary(images, k=2, levels=1, seed=0)
    assert vocab.n_nodes == 2 and vocab.n_words == 2
    centres = {bytes(d) for d in vocab.descriptors}
    assert centres == {bytes(32), bytes([0xFF] * 32)}
    # idf = ln(N / N_i): group A is in both images (0), group B in one of two (ln 2)
    weight = {bytes(d): w for d, w in zip(vocab.descriptors, vocab.weights, strict=True)}
    assert weight[bytes(32)] == 0.0
    assert weight[bytes([0xFF] * 32)] == pytest.approx(math.log(2.0), abs=0, rel=1e-15)


def test_at_most_k_descriptors_get_one_child_each() -> None:
    rng = np.random.default_rng(5)
    sets = [rng.integers(0, 256, (3, 32), dtype=np.uint8)]
    vocab = voc.build_vocabulary(sets, k=4, levels=2)
    assert vocab.n_nodes == 3 and vocab.n_words == 3
    assert np.array_equal(vocab.descriptors, sets[0])
    assert np.all(vocab.parents == 0)


def test_words_descend_to_the_nearest_child_at_every_level() -> None:
    vocab = voc.build_vocabulary(_random_sets(seed=2), k=4, levels=3, seed=3)
    queries = np.random.default_rng(9).integers(0, 256, (200, 32), dtype=np.uint8)

    def hamming(x: np.ndarray, y: np.ndarray) -> int:
        return int(np.unpackbits(x ^ y).sum())

    leaf_ids = list(np.flatnonzero(vocab.leaves) + 1)
    expected = []
    for q in queries:
        node = 0
        while True:
            kids = [i for i in range(1, vocab.n_nodes + 1) if vocab.parents[i - 1] == node]
            if not kids:
                break
            node = min(kids, key=lambda i: (hamming(q, vocab.descriptors[i - 1]), i))
        expected.append(leaf_ids.index(node))
    assert vocab.words(queries).tolist() == expected


def test_text_round_trip_and_format(tmp_path: Path) -> None:
    vocab = voc.build_vocabulary(_random_sets(), k=6, levels=2, seed=4)
    path = voc.write_vocabulary(tmp_path / "v.txt", vocab)
    text = path.read_text()
    lines = text.split("\n")
    assert lines[0] == "6 2 0 0"  # k L scoring(L1_NORM=0) weighting(TF_IDF=0)
    assert not text.endswith("\n")  # ORB-SLAM3's loader would add an empty node for it
    assert len(lines) == vocab.n_nodes + 1
    assert all(len(line.split()) == 35 for line in lines[1:])
    back = voc.read_vocabulary(path)
    assert (back.k, back.levels, back.scoring, back.weighting) == (6, 2, 0, 0)
    assert np.array_equal(back.parents, vocab.parents)
    assert np.array_equal(back.leaves, vocab.leaves)
    assert np.array_equal(back.descriptors, vocab.descriptors)
    assert np.array_equal(back.weights, vocab.weights)  # repr() round-trips floats exactly
    assert voc.read_header(path) == (6, 2, 0, 0)
    # ORB-SLAM's own ORBvoc.txt ends with a newline: the reader accepts one
    (tmp_path / "nl.txt").write_text(text + "\n")
    assert voc.read_vocabulary(tmp_path / "nl.txt").n_nodes == vocab.n_nodes


@pytest.mark.parametrize("reader", [voc.read_vocabulary, voc.read_header])
def test_a_byte_order_mark_is_one_line_naming_why(reader, tmp_path: Path) -> None:
    """ORB-SLAM3's loader would read an editor's byte-order mark as part of the header: both
    readers refuse it, naming the file, its first line and the mark."""
    vocab = voc.build_vocabulary(_random_sets(), k=6, levels=2, seed=4)
    text = voc.write_vocabulary(tmp_path / "v.txt", vocab).read_bytes()
    (tmp_path / "bom.txt").write_bytes(b"\xef\xbb\xbf" + text)
    with pytest.raises(DataFormatError, match="byte-order mark") as err:
        reader(tmp_path / "bom.txt")
    assert "bom.txt:1:" in str(err.value), str(err.value)


def test_deterministic_for_a_seed(tmp_path: Path) -> None:
    sets = _random_sets(seed=7)
    a = voc.write_vocabulary(tmp_path / "a.txt", voc.build_vocabulary(sets, k=5, levels=3, seed=1))
    b = voc.write_vocabulary(tmp_path / "b.txt", voc.build_vocabulary(sets, k=5, levels=3, seed=1))
    c = voc.write_vocabulary(tmp_path / "c.txt", voc.build_vocabulary(sets, k=5, levels=3, seed=2))
    assert a.read_bytes() == b.read_bytes()
    assert a.read_bytes() != c.read_bytes()


NODE = "0 1 " + " ".join(["7"] * 32) + " 0.5"


@pytest.mark.parametrize(
    ("content", "line", "message"),
    [
        ("10 4 0\n" + NODE, 1, "4 integers"),
        ("30 4 0 0\n" + NODE, 1, "k must be 2..20"),
        ("10 4 9 0\n" + NODE, 1, "scoring must be 0..5"),
        ("10 4 0 0\n0 1 7 7 0.5", 2, "35 fields"),
        ("10 4 0 0\n3 1 " + " ".join(["7"] * 32) + " 0.5", 2, "parent 3 is not a node"),
        ("10 4 0 0\n0 2 " + " ".join(["7"] * 32) + " 0.5", 2, "is_leaf must be 0 or 1"),
        ("10 4 0 0\n0 1 " + " ".join(["300"] * 32) + " 0.5", 2, "0..255"),
        ("10 4 0 0\n0 1 " + " ".join(["7"] * 32) + " nan", 2, "finite"),
        ("10 4 0 0\n" + NODE + "\n1 1 " + " ".join(["7"] * 32) + " 0", 3, "is a word"),
        ("10 4 0 0\n0 0 " + " ".join(["7"] * 32) + " 0", 2, "without children"),
        ("2 1 0 0\n" + "\n".join([NODE] * 3), None, "exceed a full tree"),
        ("10 4 0 0", None, "no nodes"),
    ],
)
def test_reader_names_the_bad_line(tmp_path: Path, content: str, line: int | None, message: str):
    path = tmp_path / "bad.txt"
    path.write_text(content)
    with pytest.raises(DataFormatError) as info:
        voc.read_vocabulary(path)
    assert info.value.line == line and message in str(info.value)
    assert "\n" not in str(info.value)


def test_bad_parameters_are_one_line() -> None:
    with pytest.raises(UssSlamError, match="k must be 2..20"):
        voc.build_vocabulary(_random_sets(), k=21)
    with pytest.raises(UssSlamError, match="levels must be 1..10"):
        voc.build_vocabulary(_random_sets(), levels=0)
    with pytest.raises(UssSlamError, match="no ORB descriptors"):
        voc.build_vocabulary([np.empty((0, 32), np.uint8)])


@pytest.mark.parametrize("size", [(1, 1), (1, 40), (40, 1)])
def test_a_frame_one_pixel_wide_or_high_has_no_descriptors(tmp_path: Path, size) -> None:
    """OpenCV's ORB cannot shrink it into its pyramid (a cv2.error traceback of uss-vocab
    build): no descriptors, so a sequence of such frames is the line about no descriptors."""
    import cv2

    path = tmp_path / "f.png"
    cv2.imwrite(str(path), np.full((*size, 3), 128, np.uint8))
    assert [d.shape for d in voc.orb_descriptors([path])] == [(0, 32)]


def test_uss_vocab_build_and_info(write_sequence, texture, tmp_path: Path, capsys) -> None:
    import cv2

    seq = write_sequence(n=4, size=(160, 120))
    for k, name in enumerate(sorted((seq / "rgb").iterdir())):
        cv2.imwrite(str(name), cv2.cvtColor(texture((160, 120), seed=k), cv2.COLOR_GRAY2BGR))
    out = tmp_path / "v.txt"
    argv = ["build", str(seq), "--out", str(out), "-k", "4", "-L", "2", "--stride", "2"]
    assert vocab_main(argv) == 0
    printed = capsys.readouterr().out
    vocab = voc.read_vocabulary(out)
    assert f"{vocab.n_nodes} nodes, {vocab.n_words} words" in printed
    assert "of 2 frames" in printed  # stride 2 of 4 frames
    # the same frames' descriptors, clustered again, give the same file
    images = voc.training_images([seq], stride=2)
    again = voc.build_vocabulary(voc.orb_descriptors(images), k=4, levels=2, seed=0)
    assert voc.write_vocabulary(tmp_path / "w.txt", again).read_bytes() == out.read_bytes()
    assert vocab_main(["info", str(out)]) == 0
    assert capsys.readouterr().out.startswith(f"{out}: k=4 L=2 scoring=0 weighting=0")
    # an existing --out needs --overwrite; a missing folder is one line naming it
    assert vocab_main(argv) == 1
    assert "pass --overwrite" in capsys.readouterr().err
    assert vocab_main(["build", str(tmp_path / "nope"), "--out", str(tmp_path / "x.txt")]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "nope: does not exist; expected a TUM sequence" in err
