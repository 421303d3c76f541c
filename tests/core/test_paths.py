"""The path layer (``uss_slam.core.paths``) and the errors that cross processes."""

from __future__ import annotations

import errno
import pickle
from pathlib import Path

import pytest

from uss_slam.core.cli import override_parse_line
from uss_slam.core.errors import DataFormatError, NoSpaceError
from uss_slam.core.files import no_space_errno
from uss_slam.core.hydra_lines import list_items_quoted_argv
from uss_slam.core.paths import (
    PathError,
    hydra_quoted,
    input_file,
    input_folder,
    naming_roots,
    output_file,
    output_folder,
    path_override,
)


@pytest.fixture
def tree(tmp_path: Path) -> Path:
    (tmp_path / "loop").symlink_to(tmp_path / "loop")
    (tmp_path / "a").symlink_to(tmp_path / "b")
    (tmp_path / "b").symlink_to(tmp_path / "a")
    (tmp_path / "link").symlink_to(tmp_path / "gone")
    (tmp_path / "file").write_text("x\n")
    (tmp_path / "folder").mkdir()
    (tmp_path / "to_file").symlink_to(tmp_path / "file")
    return tmp_path


@pytest.mark.parametrize(
    ("check", "name", "says"),
    [
        (input_file, "loop", "k={t}/loop: is a symbolic link that loops (to {t}/loop); expected a file"),
        (input_folder, "a/x", "k={t}/a/x: {t}/a is a symbolic link that loops (to {t}/b); expected a folder"),
        (output_file, "link", "k={t}/link: is a symbolic link to {t}/gone, which does not exist; expected a file to write"),
        (output_folder, "link/x", "k={t}/link/x: {t}/link is a symbolic link to {t}/gone, which does not exist; expected a folder to write into"),
        (input_folder, "file", "k={t}/file: is a file; expected a folder"),
        (output_folder, "file", "k={t}/file: is a file; expected a folder"),
        (input_file, "folder", "k={t}/folder: is a folder; expected a file"),
        (output_file, "folder", "k={t}/folder: is a folder; expected a file"),
        (input_file, "file/x", "k={t}/file/x: {t}/file is a file, not a folder; expected a file"),
        (output_file, "file/x", "k={t}/file/x: cannot create the output folder ({t}/file is a file); expected a file to write"),
        (input_file, "none", "k={t}/none: does not exist; expected a file"),
        (output_folder, "x" * 256, "k={t}/" + "x" * 256 + ": the name 'xxxxxxxxxxxxxxxxxxxx...xxxxxxxxxx' is 256 bytes; expected at most 255 (the longest name the file system allows)"),
    ],
)  # fmt: skip
def test_each_problem_is_one_line_naming_the_key(check, name: str, says: str, tree: Path) -> None:
    with pytest.raises(PathError) as caught:
        check(tree / name, "k")
    assert str(caught.value) == says.format(t=tree)


@pytest.mark.parametrize(
    ("check", "name"),
    [(input_file, "file"), (input_file, "to_file"), (input_folder, "folder"),
     (output_file, "to_file"), (output_file, "new.txt"), (output_folder, "folder"),
     (output_folder, "new/deeper"), (output_folder, "résumé ü")],
)  # fmt: skip
def test_usable_paths_pass(check, name: str, tree: Path) -> None:
    assert check(tree / name, "k") == tree / name
    assert not (tree / "new").exists()  # nothing created (create=False)


def test_output_folder_create_makes_it(tmp_path: Path) -> None:
    assert output_folder(tmp_path / "a" / "b", "k", create=True).is_dir()


@pytest.mark.parametrize(
    ("text", "quoted"),
    [("/data/run", "/data/run"), ("/data/résumé 1", "'/data/résumé 1'"), ("1.5", "'1.5'"),
     ("it's", "'it\\'s'"), ("null", "'null'")],
)  # fmt: skip
def test_paths_handed_on_are_quoted_where_hydra_needs_it(text: str, quoted: str) -> None:
    assert hydra_quoted(text) == quoted
    assert path_override("k", [Path("/a b"), Path("/c")]) == "k=['/a b',/c]"


def test_a_value_hydra_cannot_read_unquoted_gets_its_quoted_form() -> None:
    assert override_parse_line("out_dir=/data/résumé", "LexerNoViableAltException: ...") == (
        "out_dir: the value '/data/résumé' must be quoted for Hydra (it holds spaces or "
        "non-ASCII characters); write out_dir='/data/résumé' (in a shell: "
        "\"out_dir='/data/résumé'\")"
    )


def test_list_items_holding_equals_signs_get_their_quoted_form() -> None:
    """``train.overrides=[logger=none,model.max_iters=6]``: Hydra's lexer text would say "no
    viable alternative"; the line gives the form that works."""
    line = override_parse_line("train.overrides=[logger=none,model.max_iters=6]", "no viable ...")
    assert line == (
        "train.overrides: a list item holding '=' must be quoted for Hydra; write "
        "train.overrides=['logger=none','model.max_iters=6']"
    )
    assert override_parse_line("limit=[1", "no viable alternative at input '[1'").startswith(
        "limit=[1: no viable"
    )


@pytest.mark.parametrize(
    ("typed", "read"),
    [
        ("slam.overrides=[slam.orb.n_features=500]", "slam.overrides=['slam.orb.n_features=500']"),
        ("train.overrides=[logger=none, model.max_iters=6]",
         "train.overrides=['logger=none','model.max_iters=6']"),
        ("+train.overrides=[a=(1)]", "+train.overrides=['a=(1)']"),
        ("train.overrides=['logger=none']", "train.overrides=['logger=none']"),  # parses already
        ("x=[1,2]", "x=[1,2]"),
        ("x=['a=1',b=2]", "x=['a=1',b=2]"),  # an item with quotes: left to the parse error
        ("x=[a=[1]]", "x=[a=[1]]"),  # brackets in an item
        ("-m", "-m"),
    ],
)  # fmt: skip
def test_list_items_holding_equals_signs_are_read_quoted(typed: str, read: str) -> None:
    """Hydra's grammar reads ``=`` in a list item only quoted, so the unquoted list of another
    script's overrides has no other meaning: it is read as the quoted one."""
    assert list_items_quoted_argv([typed]) == [read]


def test_errors_cross_processes_whole() -> None:
    """A worker's error is pickled to its parent: rebuilt from its fields, never from its
    message (a full disk would name itself twice), and still a full disk there."""
    for error in (
        NoSpaceError("/out/data", errno.ENOSPC),
        DataFormatError("/seq/groundtruth.txt", "expected 8 columns", 4),
        PathError("/seq", "sequence.path", "does not exist; expected a folder"),
    ):
        again = pickle.loads(pickle.dumps(error))
        assert type(again) is type(error) and str(again) == str(error)
    assert (
        no_space_errno(pickle.loads(pickle.dumps(NoSpaceError("/o", errno.EDQUOT)))) == errno.EDQUOT
    )


def test_a_utf8_byte_order_mark_is_no_text(tmp_path: Path) -> None:
    """What Windows editors write first: read as no text (a TUM file's first stamp intact)."""
    from uss_slam.core.paths import read_text

    path = tmp_path / "gt.txt"
    path.write_bytes(b"\xef\xbb\xbf1.0 0 0 0 0 0 0 1\n")
    assert read_text(path) == "1.0 0 0 0 0 0 0 1\n"


def test_naming_roots_names_the_data_key_of_a_bad_file_inside_its_folder(tmp_path: Path) -> None:
    """A reader's line about a file inside a folder a data config names gains the key:
    ``data.target.roots=<folder>: rgb.txt: ...``; a file elsewhere keeps its own line."""
    data = {"target": {"roots": [str(tmp_path / "a"), str(tmp_path / "b")]}, "val": {"root": None}}
    with pytest.raises(PathError) as info, naming_roots(data, "data"):
        raise DataFormatError(tmp_path / "b" / "rgb.txt", "not a TUM RGB-D sequence", line=3)
    assert str(info.value) == (
        f"data.target.roots={tmp_path / 'b'}: rgb.txt, line 3: not a TUM RGB-D sequence"
    )
    data["source"] = {"root": str(tmp_path / "b")}  # one folder under two keys: both named
    with pytest.raises(PathError) as info, naming_roots(data, "data"):
        raise DataFormatError(tmp_path / "b" / "x" / "rgb.txt", "not a TUM RGB-D sequence")
    assert str(info.value).startswith(
        f"data.target.roots, data.source.root={tmp_path / 'b'}: x/rgb.txt: not a TUM"
    )
    elsewhere = DataFormatError(tmp_path / "c.txt", "bad")
    with pytest.raises(DataFormatError) as info, naming_roots(data, "data"):
        raise elsewhere
    assert info.value is elsewhere


def test_a_yaml_key_given_twice_is_refused_with_both_lines(tmp_path: Path) -> None:
    """YAML loaders keep the last of a key given twice without a word; the path layer's
    reader names the file, the line and the first one."""
    from uss_slam.core.paths import read_yaml

    path = tmp_path / "intrinsics.yaml"
    path.write_text("fx: 1.0\nfy: 2.0\nnested:\n  a: 1\n  a: 2\n")
    with pytest.raises(
        DataFormatError, match=r"intrinsics.yaml:5: the key 'a' is given twice \(first at line 4\)"
    ):
        read_yaml(path)
    path.write_text("fx: 1.0\n\tfy: 2.0\n")
    with pytest.raises(DataFormatError, match=r"intrinsics.yaml:2: not valid YAML"):
        read_yaml(path)
    path.write_text("fx: 1.0\nlist: [1, 1]\n")
    assert read_yaml(path) == {"fx": 1.0, "list": [1, 1]}


@pytest.mark.parametrize("name", ["no\nsuch", "a\rb", "c\x1b[31md", "e\x7f"])
def test_a_control_character_in_a_path_keeps_the_line_one_line(tmp_path: Path, name: str) -> None:
    """A newline in a file's name made the error two lines; a terminal's escape coloured it."""
    escaped = repr(name)[1:-1]
    with pytest.raises(PathError) as missing:
        input_file(tmp_path / name, "--gt")
    assert str(missing.value) == (f"--gt={tmp_path}/{escaped}: does not exist; expected a file")
    assert str(DataFormatError(name, "bad", line=3)) == f"{escaped}:3: bad"
    assert str(NoSpaceError(name)) == f"no space left on device while writing {escaped}"
    line = override_parse_line(f"out_dir=/r/{name}", "LexerNoViableAltException: ...")
    assert line.isprintable() and escaped in line
