"""A small DBoW2 ORB vocabulary for ORB-SLAM3, built from the frames of TUM RGB-D sequences.

ORB-SLAM3 needs a bag-of-words vocabulary (place recognition for relocalisation and loop
closing, and the BoW-guided matching of tracking); its own ``ORBvoc.txt`` (139 MB, k = 10,
L = 6) cannot be downloaded here. This module builds one the way DBoW2's
``TemplatedVocabulary::create`` does, and writes it in the text format that ORB-SLAM3's
``loadFromTextFile`` reads:

1. ORB descriptors of every frame (``cv2.ORB_create`` with ORB-SLAM's settings: 1000 features,
   scale 1.2, 8 levels, FAST threshold 20, 31-px patches, FAST score), one set per image.
2. Hierarchical k-majority clustering (DBoW2's "k-medians" for binary descriptors): k-means++
   seeding (probability proportional to the Hamming distance to the nearest centre, as DBoW2's
   ``initiateClustersKMpp``), assignment to the nearest centre (Hamming, the first on ties),
   centres recomputed as the bitwise majority of their members (a bit is set when at least
   half of the members have it, ``FORB::meanValue``), until the assignment no longer changes
   (or ``max_iterations``). A node with at most ``k`` descriptors gets one child per descriptor;
   a child is split again while its level is below ``L`` and it holds more than one descriptor.
   The leaves are the words. Unlike DBoW2, a cluster that ends up empty gets no node.
3. TF-IDF weights: every training descriptor is passed down the tree (as ``transform`` does);
   a word's weight is ``idf = ln(N_images / n_images_containing_it)``, 0 for a word no training
   image reaches (ORB-SLAM3 then ignores it).

Text format (``loadFromTextFile``): first line ``k L scoring weighting`` (:data:`L1_NORM` = 0,
:data:`TF_IDF` = 0, DBoW2's ``ScoringType`` / ``WeightingType`` enums), then one line per node
except the root, in node-id order (node ids start at 1; the root is 0):
``parent_id is_leaf d0 d1 ... d31 weight`` with the 32 descriptor bytes as integers 0-255.
The loader reads lines until end of file, so a final newline would make it add an empty node
under the root: :func:`write_vocabulary` ends the last line without one. The loader also
reserves room for ``(k^(L+1) - 1) / (k - 1)`` nodes and keeps pointers into that storage, so
a file with more nodes than a full tree of ``k`` and ``L`` is refused by :func:`read_vocabulary`.

Deterministic: the same frames, parameters and ``seed`` give the same file, byte for byte.
NumPy and OpenCV only (no torch).
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from uss_slam.core.errors import DataFormatError, UssSlamError
from uss_slam.core.files import write_text_atomic
from uss_slam.core.images import read_colour
from uss_slam.core.paths import BOM, input_file, read_text
from uss_slam.core.ranges import check_stride
from uss_slam.core.tum_io import StrPath, is_file, read_file_list

DESCRIPTOR_BYTES = 32
"""ORB descriptor length (``FORB::L``)."""
L1_NORM = 0
"""DBoW2 ``ScoringType::L1_NORM`` (the scoring of ORB-SLAM's vocabulary)."""
TF_IDF = 0
"""DBoW2 ``WeightingType::TF_IDF`` (the weighting of ORB-SLAM's vocabulary)."""
MAX_BRANCHING = 20
"""``loadFromTextFile`` refuses ``k`` above 20 and ``L`` outside 1..10."""
MAX_LEVELS = 10
ORB_SETTINGS = {
    "nfeatures": 1000,
    "scaleFactor": 1.2,
    "nlevels": 8,
    "edgeThreshold": 19,
    "patchSize": 31,
    "fastThreshold": 20,
}
"""``cv2.ORB_create`` keyword arguments matching ORB-SLAM's TUM settings."""

_CHUNK = 1 << 16  # descriptors per block of the distance computation (bounds memory)


# --------------------------------------------------------------------------- the vocabulary


@dataclass(frozen=True)
class Vocabulary:
    """A DBoW2 vocabulary tree. Node ``i + 1`` is row ``i`` of the arrays (the root, node 0, is
    implicit, as in the text file).

    ``parents`` (N,) int64 parent node ids (0 = the root); ``leaves`` (N,) bool, True for words;
    ``descriptors`` (N, 32) uint8; ``weights`` (N,) float64 idf of the words, 0 for inner nodes.
    """

    k: int
    levels: int
    parents: np.ndarray
    leaves: np.ndarray
    descriptors: np.ndarray
    weights: np.ndarray
    scoring: int = L1_NORM
    weighting: int = TF_IDF

    @property
    def n_nodes(self) -> int:
        """Nodes without the root (lines of the file after the header)."""
        return len(self.parents)

    @property
    def n_words(self) -> int:
        return int(self.leaves.sum())

    def children(self) -> np.ndarray:
        """``(N + 1, max children)`` node ids of each node's children in order, -1 padded."""
        counts = np.bincount(self.parents, minlength=self.n_nodes + 1)
        table = np.full((self.n_nodes + 1, max(int(counts.max(initial=0)), 1)), -1, np.int64)
        fill = np.zeros(self.n_nodes + 1, np.int64)
        for node, parent in enumerate(self.parents.tolist(), start=1):
            table[parent, fill[parent]] = node
            fill[parent] += 1
        return table

    def words(self, descriptors: np.ndarray) -> np.ndarray:
        """Word index (0-based, in node-id order as DBoW2 numbers them) of each ``(M, 32)``
        uint8 descriptor: passed down the tree to the nearest child at every level."""
        table = self.children()
        nodes = _nearest_leaf_nodes(self, table, _as_words64(descriptors))
        word_of_node = np.full(self.n_nodes + 1, -1, np.int64)
        leaf_nodes = np.flatnonzero(self.leaves) + 1
        word_of_node[leaf_nodes] = np.arange(len(leaf_nodes))
        return word_of_node[nodes]


def _as_words64(descriptors: np.ndarray) -> np.ndarray:
    """``(M, 32)`` uint8 -> ``(M, 4)`` uint64 (a view when contiguous) for XOR + popcount."""
    d = np.ascontiguousarray(descriptors, dtype=np.uint8).reshape(-1, DESCRIPTOR_BYTES)
    return d.view(np.uint64)


def _hamming(a64: np.ndarray, b64: np.ndarray) -> np.ndarray:
    """``(M, K)`` Hamming distances between ``(M, 4)`` and ``(K, 4)`` uint64 descriptors."""
    out = np.empty((len(a64), len(b64)), np.int32)
    for start in range(0, len(a64), _CHUNK):
        block = a64[start : start + _CHUNK, None, :] ^ b64[None, :, :]
        out[start : start + _CHUNK] = np.bitwise_count(block).sum(axis=2, dtype=np.int32)
    return out


def _nearest_leaf_nodes(vocab: Vocabulary, table: np.ndarray, d64: np.ndarray) -> np.ndarray:
    """Node id of the leaf each descriptor reaches from the root (DBoW2's ``transform``)."""
    desc64 = _as_words64(vocab.descriptors)
    nodes = np.zeros(len(d64), np.int64)
    active = np.flatnonzero(table[nodes, 0] >= 0)
    while len(active):
        for start in range(0, len(active), _CHUNK):
            idx = active[start : start + _CHUNK]
            kids = table[nodes[idx]]  # (m, c), -1 padded
            valid = kids >= 0
            cand = desc64[np.where(valid, kids - 1, 0)]  # (m, c, 4)
            dist = np.bitwise_count(d64[idx, None, :] ^ cand).sum(axis=2, dtype=np.int32)
            dist[~valid] = np.iinfo(np.int32).max
            nodes[idx] = kids[np.arange(len(idx)), dist.argmin(axis=1)]
        active = active[table[nodes[active], 0] >= 0]
    return nodes


# --------------------------------------------------------------------------- clustering


def _seed_centres(d64: np.ndarray, k: int, rng: np.random.Generator) -> list[int]:
    """k-means++ seeding as DBoW2: indices of up to ``k`` initial centres."""
    first = int(rng.integers(0, len(d64)))
    chosen = [first]
    min_dist = _hamming(d64, d64[first : first + 1])[:, 0].astype(np.float64)
    while len(chosen) < k:
        total = float(min_dist.sum())
        if total <= 0:
            break  # every descriptor equals a centre already
        cut = 0.0
        while cut == 0.0:
            cut = float(rng.uniform(0.0, total))
        index = int(np.searchsorted(np.cumsum(min_dist), cut, side="left"))
        index = min(index, len(d64) - 1)
        chosen.append(index)
        np.minimum(min_dist, _hamming(d64, d64[index : index + 1])[:, 0], out=min_dist)
    return chosen


def _majority(bits: np.ndarray) -> np.ndarray:
    """Bitwise majority (ties set the bit, as ``FORB::meanValue``) of ``(n, 256)`` 0/1 bits."""
    need = (len(bits) + 1) // 2
    return np.packbits(bits.sum(axis=0, dtype=np.int64) >= need)


def _k_majority(
    d64: np.ndarray, bits: np.ndarray, k: int, rng: np.random.Generator, max_iterations: int
) -> tuple[np.ndarray, np.ndarray]:
    """Cluster ``(n, 4)`` descriptors (``bits`` their ``(n, 256)`` unpacked bits) into at most
    ``k`` groups; returns ``(centres (c, 32) uint8, assignment (n,) int)``."""
    centres = np.ascontiguousarray(d64[_seed_centres(d64, k, rng)]).view(np.uint8)
    assign = _hamming(d64, _as_words64(centres)).argmin(axis=1)
    for _ in range(max_iterations):
        updated = centres.copy()
        for c in range(len(centres)):
            members = assign == c
            if members.any():  # an empty cluster keeps its centre
                updated[c] = _majority(bits[members])
        new_assign = _hamming(d64, _as_words64(updated)).argmin(axis=1)
        centres = updated
        if np.array_equal(new_assign, assign):
            break
        assign = new_assign
    return centres, assign


def build_vocabulary(
    descriptor_sets: Sequence[np.ndarray],
    *,
    k: int = 10,
    levels: int = 4,
    seed: int = 0,
    max_iterations: int = 100,
) -> Vocabulary:
    """Build a vocabulary from one ``(n_i, 32)`` uint8 descriptor array per training image.

    ``k`` branching factor (2..20), ``levels`` depth L (1..10), ``max_iterations`` cap of the
    k-majority iterations at each node (DBoW2 has none; binary k-majority almost always
    converges long before). Raises :class:`UssSlamError` for bad parameters or no descriptors.
    """
    if not 2 <= k <= MAX_BRANCHING:
        raise UssSlamError(
            f"vocabulary: k must be 2..{MAX_BRANCHING} (ORB-SLAM3's loader), got {k}"
        )
    if not 1 <= levels <= MAX_LEVELS:
        raise UssSlamError(
            f"vocabulary: levels must be 1..{MAX_LEVELS} (ORB-SLAM3's loader), got {levels}"
        )
    if max_iterations < 1:
        raise UssSlamError(f"vocabulary: max_iterations must be >= 1, got {max_iterations}")
    sets = [np.asarray(d, dtype=np.uint8).reshape(-1, DESCRIPTOR_BYTES) for d in descriptor_sets]
    all_desc = np.concatenate(sets) if sets else np.empty((0, DESCRIPTOR_BYTES), np.uint8)
    if len(all_desc) == 0:
        raise UssSlamError("vocabulary: no ORB descriptors to cluster (the frames have no texture)")
    d64 = _as_words64(all_desc)
    bits = np.unpackbits(all_desc, axis=1)  # bit 7 of byte 0 first, as FORB
    rng = np.random.default_rng(seed)

    parents: list[int] = []
    descs: list[np.ndarray] = []
    has_children: list[bool] = [False]  # index = node id (root first)

    def step(parent: int, members: np.ndarray, level: int) -> None:
        if len(members) <= k:
            centres = all_desc[members]
            groups = [members[i : i + 1] for i in range(len(members))]
        else:
            centres, assign = _k_majority(d64[members], bits[members], k, rng, max_iterations)
            groups = [members[assign == c] for c in range(len(centres))]
        ids = []
        for centre, group in zip(centres, groups, strict=True):
            if len(group) == 0:
                continue
            parents.append(parent)
            descs.append(centre)
            has_children.append(False)
            ids.append((len(parents), group))
        has_children[parent] = has_children[parent] or bool(ids)
        if level < levels:
            for node, group in ids:
                if len(group) > 1:
                    step(node, group, level + 1)

    step(0, np.arange(len(all_desc)), 1)
    leaves = ~np.asarray(has_children[1:], bool)
    vocab = Vocabulary(
        k=k,
        levels=levels,
        parents=np.asarray(parents, np.int64),
        leaves=leaves,
        descriptors=np.asarray(descs, np.uint8).reshape(-1, DESCRIPTOR_BYTES),
        weights=np.zeros(len(parents), np.float64),
    )
    # idf: ln(N / N_i), N_i = training images in which word i occurs (via the tree, as DBoW2).
    words = vocab.words(all_desc)
    image_of = np.repeat(np.arange(len(sets)), [len(s) for s in sets])
    pairs = np.unique(image_of * vocab.n_words + words)
    containing = np.bincount(pairs % vocab.n_words, minlength=vocab.n_words)
    idf = np.zeros(vocab.n_words)
    seen = containing > 0
    idf[seen] = np.log(len(sets) / containing[seen])
    vocab.weights[np.flatnonzero(leaves)] = idf
    return vocab


# --------------------------------------------------------------------------- text file


def write_vocabulary(path: StrPath, vocab: Vocabulary) -> Path:
    """Write ``vocab`` in DBoW2's text format (module docstring), without a final newline."""
    path = Path(path)
    lines = [f"{vocab.k} {vocab.levels} {vocab.scoring} {vocab.weighting}"]
    for parent, leaf, desc, weight in zip(
        vocab.parents.tolist(),
        vocab.leaves.tolist(),
        vocab.descriptors.tolist(),
        vocab.weights.tolist(),
        strict=True,
    ):
        lines.append(f"{parent} {int(leaf)} {' '.join(map(str, desc))} {float(weight)!r}")
    try:  # atomically: a killed run never leaves half a vocabulary under the final name
        write_text_atomic(path, "\n".join(lines))
    except OSError as err:
        raise DataFormatError(path, f"cannot write the vocabulary ({err.strerror})") from None
    return path


def max_nodes(k: int, levels: int) -> int:
    """Nodes of a full tree, root included: ``(k^(L+1) - 1) / (k - 1)`` (the loader's room)."""
    return (k ** (levels + 1) - 1) // (k - 1)


VOCABULARY_FILE = "expected a DBoW2 text vocabulary file"


def read_header(path: StrPath) -> tuple[int, int, int, int]:
    """``(k, L, scoring, weighting)`` of a vocabulary text file, checked as ORB-SLAM3's loader
    does (it exits the process on a bad header, so this runs first)."""
    path = Path(path)
    input_file(path, None, VOCABULARY_FILE)
    _no_byte_order_mark(path)
    try:
        with open(path, encoding="ascii") as fh:
            first = fh.readline()
            nodes = [fh.readline() for _ in range(HEADER_NODES_CHECKED)]
    except (OSError, UnicodeDecodeError):
        raise DataFormatError(path, f"not a DBoW2 text vocabulary; {VOCABULARY_FILE}") from None
    header = _parse_header(path, first)
    for number, line in enumerate(nodes, start=2):
        if line.strip():
            _check_orb_node(path, line, number)
    return header


def _no_byte_order_mark(path: Path) -> None:
    """A vocabulary saved by an editor that writes a UTF-8 byte-order mark first is refused
    naming it: ORB-SLAM3's loader reads the mark as part of the header (other text files take
    the mark as no text)."""
    try:
        with open(path, "rb") as fh:
            start = fh.read(len(BOM))
    except OSError:
        return  # read_text / open name the problem
    if start == BOM:
        raise DataFormatError(
            path,
            "starts with a UTF-8 byte-order mark (an editor's), which ORB-SLAM3's loader "
            "reads as part of the header; save the file without it",
            1,
        )


HEADER_NODES_CHECKED = 20
"""Node lines :func:`read_header` checks for ORB descriptors (a vocabulary of another
descriptor shows on its first node)."""


def _check_orb_node(path: Path, line: str, number: int) -> None:
    """A node line holds ``parent is_leaf`` + 32 integer bytes + ``weight``: a vocabulary of
    another descriptor (BRISK's or AKAZE's bytes, SURF's floats) is one line naming it."""
    values = line.split()[2:-1]
    if len(values) != DESCRIPTOR_BYTES or not all(v.isdigit() and int(v) <= 255 for v in values):
        kind = "floats" if any("." in v or "e" in v.lower() for v in values) else "values"
        raise DataFormatError(
            path,
            f"a node of {len(values)} descriptor {kind}: built for another descriptor; "
            f"ORB-SLAM3 needs ORB's {DESCRIPTOR_BYTES} bytes (integers 0..255) per node",
            number,
        )


def _parse_header(path: Path, line: str) -> tuple[int, int, int, int]:
    fields = line.split()
    try:
        k, levels, scoring, weighting = (int(f) for f in fields)
    except ValueError:
        raise DataFormatError(
            path,
            f"expected the DBoW2 text header 'k L scoring weighting' (4 integers), got {line.strip()[:60]!r}",
            1,
        ) from None
    if not (2 <= k <= MAX_BRANCHING and 1 <= levels <= MAX_LEVELS):
        raise DataFormatError(
            path, f"k must be 2..{MAX_BRANCHING} and L 1..{MAX_LEVELS}, got k={k} L={levels}", 1
        )
    if not (0 <= scoring <= 5 and 0 <= weighting <= 3):
        raise DataFormatError(
            path,
            f"scoring must be 0..5 and weighting 0..3 (DBoW2 enums), got {scoring} {weighting}",
            1,
        )
    return k, levels, scoring, weighting


def read_vocabulary(path: StrPath) -> Vocabulary:
    """Read and check a DBoW2 text vocabulary (this module's or ORB-SLAM's ``ORBvoc.txt``).

    Checks what ORB-SLAM3's loader assumes without checking: 35 fields per line, parents
    defined before their children, bytes 0..255, finite weights >= 0, leaf flags consistent
    with the tree (a word has no children, an inner node has some), at most
    :func:`max_nodes` nodes. Errors name the line. One final newline is accepted.
    """
    path = Path(path)
    _no_byte_order_mark(path)
    text = read_text(path, "expected a DBoW2 text vocabulary file", encoding="ascii")
    lines = text.split("\n")
    if len(lines) > 1 and lines[-1] == "":
        lines.pop()
    k, levels, scoring, weighting = _parse_header(path, lines[0])
    n = len(lines) - 1
    if n == 0:
        raise DataFormatError(path, "has a header but no nodes")
    if n + 1 > max_nodes(k, levels):
        raise DataFormatError(
            path,
            f"{n} nodes exceed a full tree of k={k}, L={levels} ({max_nodes(k, levels) - 1}); "
            "ORB-SLAM3's loader would overrun its node storage",
        )
    parents = np.empty(n, np.int64)
    leaves = np.empty(n, bool)
    descs = np.empty((n, DESCRIPTOR_BYTES), np.uint8)
    weights = np.empty(n, np.float64)
    for i, line in enumerate(lines[1:]):
        number = i + 2
        fields = line.split()
        if len(fields) != DESCRIPTOR_BYTES + 3:
            raise DataFormatError(
                path,
                f"expected 'parent is_leaf' + {DESCRIPTOR_BYTES} descriptor bytes + 'weight' "
                f"({DESCRIPTOR_BYTES + 3} fields), got {len(fields)}",
                number,
            )
        try:
            parent, leaf = int(fields[0]), int(fields[1])
            values = [int(f) for f in fields[2:-1]]
            weight = float(fields[-1])
        except ValueError:
            raise DataFormatError(
                path, "parent, is_leaf and the descriptor bytes must be integers", number
            ) from None
        if not 0 <= parent <= i:
            raise DataFormatError(
                path, f"parent {parent} is not a node defined before this one (0..{i})", number
            )
        if leaf not in (0, 1):
            raise DataFormatError(path, f"is_leaf must be 0 or 1, got {leaf}", number)
        if min(values) < 0 or max(values) > 255:
            raise DataFormatError(path, "descriptor bytes must be 0..255", number)
        if not (math.isfinite(weight) and weight >= 0):
            raise DataFormatError(
                path, f"weight must be a finite number >= 0, got {weight}", number
            )
        if parent > 0 and leaves[parent - 1]:
            raise DataFormatError(
                path, f"parent {parent} is a word (is_leaf 1) and cannot have children", number
            )
        parents[i], leaves[i], descs[i], weights[i] = parent, bool(leaf), values, weight
    inner = np.flatnonzero(~leaves) + 1
    childless = inner[np.bincount(parents, minlength=n + 1)[inner] == 0]
    if len(childless):
        raise DataFormatError(
            path, "inner node (is_leaf 0) without children", int(childless[0]) + 1
        )
    return Vocabulary(k, levels, parents, leaves, descs, weights, scoring, weighting)


# --------------------------------------------------------------------------- frames


def training_images(
    folders: Sequence[StrPath], *, stride: int = 1, max_frames: int | None = None
) -> list[Path]:
    """Colour images listed in each folder's ``rgb.txt``: every ``stride``-th, at most
    ``max_frames`` per folder. Every listed file must exist."""
    if stride < 1 or (max_frames is not None and max_frames < 1):
        raise UssSlamError(
            f"vocabulary: stride must be >= 1 and max_frames >= 1 (got {stride}, {max_frames})"
        )
    images: list[Path] = []
    for folder in folders:
        folder = Path(folder)
        if not folder.is_dir():
            raise DataFormatError(folder, "not a folder; expected a TUM sequence with rgb.txt")
        listing = read_file_list(folder / "rgb.txt")
        check_stride(stride, len(listing), "--stride", folder)
        chosen = [listing.resolve(i) for i in range(0, len(listing), stride)]
        if max_frames is not None:
            chosen = chosen[:max_frames]
        if not chosen:
            raise DataFormatError(listing.path, "lists no images")
        for image in chosen:
            if not is_file(image):
                raise DataFormatError(image, f"file not found (listed in {listing.path})")
        images += chosen
    return images


def orb_descriptors(images: Sequence[StrPath], n_features: int = 1000) -> list[np.ndarray]:
    """``(n_i, 32)`` uint8 ORB descriptors of each image (grey as ``cvtColor(BGR2GRAY)``)."""
    orb = cv2.ORB_create(**{**ORB_SETTINGS, "nfeatures": n_features})
    orb.setScoreType(cv2.ORB_FAST_SCORE)  # ORB-SLAM ranks corners by FAST response
    sets = []
    for image in images:
        bgr = read_colour(image)
        gray = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)
        # a frame 1 px wide or high has no corner (and OpenCV's pyramid cannot shrink it)
        desc = None if min(gray.shape) < 2 else orb.detectAndCompute(gray, None)[1]
        sets.append(np.empty((0, DESCRIPTOR_BYTES), np.uint8) if desc is None else desc)
    return sets


@dataclass(frozen=True)
class BuildReport:
    """What :func:`build_from_sequences` did: images, descriptors, nodes, words, seconds.

    ``zero_weight_words``: words ORB-SLAM3 will ignore (idf 0: in every training image, or
    reached by none)."""

    path: Path
    images: int
    descriptors: int
    nodes: int
    words: int
    zero_weight_words: int
    extract_s: float
    cluster_s: float


def build_from_sequences(
    folders: Sequence[StrPath],
    out: StrPath,
    *,
    k: int = 10,
    levels: int = 4,
    stride: int = 5,
    max_frames: int | None = None,
    n_features: int = 1000,
    seed: int = 0,
    max_iterations: int = 100,
) -> BuildReport:
    """Extract, cluster, weight and write a vocabulary from TUM sequence folders."""
    if n_features < 1:
        raise UssSlamError(f"vocabulary: n_features must be >= 1, got {n_features}")
    images = training_images(folders, stride=stride, max_frames=max_frames)
    start = time.perf_counter()
    sets = orb_descriptors(images, n_features)
    extracted = time.perf_counter()
    where = ", ".join(str(folder) for folder in folders)
    if not any(len(s) for s in sets):
        why = "the frames have no texture"
        if n_features < 8:  # ORB shares the budget among its pyramid's levels
            why += f", or --features={n_features} is too small a budget for 8 pyramid levels"
        raise UssSlamError(
            f"{where}: no ORB descriptors in the {len(images)} training frames ({why}); "
            "expected frames with corners to cluster"
        )
    vocab = build_vocabulary(sets, k=k, levels=levels, seed=seed, max_iterations=max_iterations)
    path = write_vocabulary(out, vocab)
    done = time.perf_counter()
    return BuildReport(
        path=path,
        images=len(images),
        descriptors=sum(len(s) for s in sets),
        nodes=vocab.n_nodes,
        words=vocab.n_words,
        zero_weight_words=int((vocab.weights[vocab.leaves] == 0).sum()),
        extract_s=extracted - start,
        cluster_s=done - extracted,
    )
