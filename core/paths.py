"""The one path layer: every console script checks each input and output path it is given here,
before any work, and says what is wrong with it in one line of one form:

    <key>=<path>: <what is wrong>; expected <what the argument takes>

(``<path>: ...`` for a positional argument, which has no key). What is checked, for every kind
of path (:func:`input_file`, :func:`input_folder`, :func:`output_file`, :func:`output_folder`):

- a name longer than the file system allows (255 bytes) or a path of 4096 bytes or more;
- a symbolic link that loops (the path itself, or a folder on the way to it);
- a symbolic link to nothing (a dangling link: ``mkdir`` would say "File exists");
- a file where a folder is expected (the path, or a folder on the way to it), and a folder
  where a file is expected;
- a location that cannot be written (read-only, no permission, a read-only file system),
  proved by creating a file there: an output is checked before any work, not after it; an
  output file that exists read-only is not replaced;
- a named pipe, a socket or a device where a file or folder is expected (a pipe would block
  its reader; ``/dev/null`` is no file to write a result into).

Pure Python (floor 0): every package may import it. The problems are found from ``os.stat`` /
``os.lstat`` error numbers, never from an error's text.
"""

from __future__ import annotations

import errno
import os
import re
import stat
import tempfile
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from os import PathLike
from pathlib import Path
from typing import Any

from uss_slam.core import output_keys
from uss_slam.core.errors import DataFormatError, UssSlamError, shown

NAME_MAX_DEFAULT, PATH_MAX_DEFAULT = 255, 4096


class PathError(DataFormatError):
    """A path argument the system cannot use as asked (exit code 1); the message names the
    key (or the path of a positional argument), the problem and what was expected. A
    :class:`DataFormatError` (``path``, ``detail``) for the readers that catch those."""

    def __init__(self, path: str | PathLike[str], key: str | None, message: str) -> None:
        UssSlamError.__init__(self, f"{where(path, key)}: {message}")
        self.path, self.key, self.line, self.detail = str(path), key, None, message

    def __reduce__(self) -> tuple[object, ...]:
        return (type(self), (self.path, self.key, self.detail))


@contextmanager
def naming(key: str, path: str | PathLike[str]) -> Iterator[None]:
    """A reader's :class:`DataFormatError` about the file ``path`` itself (no line), raised
    inside, becomes the path layer's line naming ``key`` too: ``ckpt_path=<path>: ...``."""
    try:
        yield
    except Exception as error:  # the reader's own, or one a library wrapped (Hydra's instantiate)
        found: BaseException | None = error
        while found is not None and not isinstance(found, DataFormatError):
            found = found.__cause__
        if (not isinstance(found, DataFormatError) or found.line is not None
                or getattr(found, "key", None) is not None
                or Path(found.path).absolute() != Path(path).absolute()):  # fmt: skip
            raise
        raise PathError(path, key, found.detail) from None


def where(path: str | PathLike[str], key: str | None) -> str:
    """``key=path`` (``path`` for a positional argument): how an error line names it."""
    return shown(path) if key is None else f"{key}={shown(path)}"


def _limit(name: str, default: int) -> int:
    try:
        value = os.pathconf("/", name)
    except (OSError, ValueError, AttributeError):
        return default
    return value if value > 0 else default


def too_long(path: str | PathLike[str]) -> str | None:
    """Why the system cannot create ``path`` at all (a name over ``NAME_MAX`` bytes, the whole
    over ``PATH_MAX``), else None."""
    path = Path(path)
    name_max = _limit("PC_NAME_MAX", NAME_MAX_DEFAULT)
    path_max = _limit("PC_PATH_MAX", PATH_MAX_DEFAULT)
    for part in path.parts:
        size = len(os.fsencode(part))
        if size > name_max and part != path.anchor:
            shown = part if len(part) <= 40 else part[:20] + "..." + part[-10:]
            return (
                f"the name {shown!r} is {size} bytes; expected at most {name_max} (the longest "
                "name the file system allows)"
            )
    size = len(os.fsencode(str(path.absolute())))
    if size >= path_max:
        return (
            f"the path is {size} bytes; expected fewer than {path_max} (the longest path the "
            "system allows)"
        )
    return None


def not_utf8(path: str | PathLike[str]) -> str | None:
    """Why ``path`` cannot be written into a report or a JSON file: a name holding bytes that
    are not UTF-8 (a Latin-1 ``\xe9`` from another system, read by Python as a surrogate),
    else None."""
    raw = os.fsencode(path)
    try:
        raw.decode("utf-8")
    except UnicodeDecodeError as error:
        return (
            f"the path holds a byte that is not UTF-8 (0x{raw[error.start]:02x} at byte "
            f"{error.start}); expected a UTF-8 name (rename it)"
        )
    return None


def home_expanded(text: str) -> str:
    """``text`` with a ``~`` or ``~user`` that starts it expanded as a shell expands it (the home
    folder of the user, of ``user``), else as it is (``~nobody-such/x``: the shell keeps it
    too). The one rule of every path a user gives on a command line: bash expands ``~`` only at
    a word's start or after ``name=``, so ``--out=~/x``, ``sh``'s ``key=~/x`` and a quoted
    ``'~/x'`` reach the scripts unexpanded, where nobody means a folder named ``~``."""
    if not text.startswith("~"):
        return text
    return os.path.expanduser(text)


def _unexpanded_home(path: Path) -> str | None:
    """A path still starting with ``~`` here: ``~user`` of a user this system does not have
    (the command line's paths are expanded, :func:`home_expanded`), or a config file's value
    (read as written): it would name a folder called ``~`` in the working folder."""
    first = path.parts[0] if path.parts else ""
    if not first.startswith("~") or (first != "~" and path.exists()):
        return None
    if home_expanded(str(path)) == str(path) and first == "~":
        return (
            "starts with '~', and the home folder is not known (HOME is not set); expected the "
            "path written out"
        )
    if home_expanded(str(path)) == str(path):
        return (
            f"starts with {first!r}, and this system has no user {first[1:]!r} (it would be a "
            f"folder named {first!r}); expected ~/..., ~USER/... or the path written out"
        )
    return (
        f"starts with {first!r}, which a config file's value does not expand (it would be a "
        f"folder named {first!r}); expected the path written out, or given on the command line"
    )


def _prefixes(path: Path) -> list[Path]:
    """``path``'s folders from the top down, then ``path`` itself (``a``, ``a/b``, ``a/b/c``)."""
    parts = path.parts
    return [Path(*parts[: i + 1]) for i in range(len(parts))]


def _stat_errno(path: Path) -> int | None:
    try:
        os.stat(path)
    except OSError as error:
        return error.errno
    return None


def _link_problem(link: Path) -> str | None:
    """What is wrong with the symbolic link ``link`` (it loops, or points nowhere), else None."""
    code = _stat_errno(link)
    if code == errno.ELOOP:
        return f"{link} is a symbolic link that loops (to {os.readlink(link)})"
    if code == errno.ENOENT:
        return f"{link} is a symbolic link to {os.readlink(link)}, which does not exist"
    return None


def structure_problem(
    path: str | PathLike[str], *, folder: bool | None, output: bool = False
) -> str | None:
    """What keeps ``path`` from being used, found without writing anything: its length, a link
    that loops or dangles (``path`` or a folder on the way), a file where a folder must be (on
    the way, or ``path`` when ``folder`` is True), a folder where a file must be (``folder``
    False); None when it exists as asked or does not exist (``missing`` is the caller's call).

    The texts read after ``<key>=<path>: ``."""
    path = Path(path)
    if not path.is_absolute() and working_folder_gone():
        return (
            "a relative path, and the working folder no longer exists (it was deleted); "
            "give an absolute path or run from an existing folder"
        )
    reason = too_long(path) or not_utf8(path) or _unexpanded_home(path)
    if reason:
        return reason
    for prefix in _prefixes(path):
        if os.path.islink(prefix):
            problem = _link_problem(prefix)
            if problem:
                return problem.replace(f"{path} is ", "is ", 1) if prefix == path else problem
        try:
            os.stat(prefix)
        except FileNotFoundError:
            return None  # the rest does not exist
        except OSError as error:
            if error.errno == errno.ENOTDIR:
                return None  # reported below by the prefix before it
            return f"cannot look it up ({error.strerror or type(error).__name__})"
        is_dir = os.path.isdir(prefix)
        if prefix != path and not is_dir:
            if output:
                return f"cannot create the output folder ({prefix} is a file)"
            return f"{prefix} is a file, not a folder"
        if prefix == path and not is_dir and not os.path.isfile(prefix):
            return f"is {_special_kind(prefix)}, not a regular file"
        if prefix == path and folder is True and not is_dir:
            return "is a file; expected a folder"
        if prefix == path and folder is False and is_dir:
            return "is a folder; expected a file"
    return None


def _special_kind(path: Path) -> str:
    """What a path that is neither a folder nor a regular file is (a FIFO would block a reader
    for ever; a device is no file to read or replace)."""
    mode = os.stat(path).st_mode
    if stat.S_ISFIFO(mode):
        return "a named pipe (FIFO)"
    if stat.S_ISSOCK(mode):
        return "a socket"
    return "a device"


def _fail(path: str | PathLike[str], key: str | None, problem: str, expected: str) -> PathError:
    tail = f"; {expected}" if expected and "; expected" not in problem else ""
    return PathError(path, key, f"{problem}{tail}")


def input_file(
    path: str | PathLike[str], key: str | None = None, expected: str = "expected a file"
) -> Path:
    """An existing, readable file; else :class:`PathError` (``expected``: what the argument
    takes, e.g. ``expected a uss-train checkpoint``)."""
    problem = structure_problem(path, folder=False)
    if problem is None and not os.path.lexists(path):
        problem = "does not exist"
    if problem is None and not os.access(path, os.R_OK):
        problem = "cannot be read (permission denied)"
    if problem:
        raise _fail(path, key, problem, expected)
    return Path(path)


def input_folder(
    path: str | PathLike[str], key: str | None = None, expected: str = "expected a folder"
) -> Path:
    """An existing folder that can be listed; else :class:`PathError`."""
    problem = structure_problem(path, folder=True)
    if problem is None and not os.path.lexists(path):
        problem = "does not exist"
    if problem is None and not os.access(path, os.R_OK | os.X_OK):
        problem = "cannot be read (permission denied)"
    if problem:
        raise _fail(path, key, problem, expected)
    return Path(path)


def distinct_folders(folders: Iterable[str | PathLike[str]], key: str | None) -> list[Path]:
    """``folders`` as paths, checked to name each folder once whatever the spelling (a link,
    ``./``, a trailing ``/``: compared resolved). The one policy for an input folder given twice
    (``uss-vocab build``'s sequences, ``uss-eval``'s and ``uss-eval compare``'s ``--sequence``,
    the ``roots`` of a data config): refused, as a name listed twice in a list of names is,
    with one line ``<key>=<path>: given twice (as <first>); expected each folder once`` (its
    frames would otherwise count twice)."""
    seen: dict[Path, Path] = {}
    for folder in map(Path, folders):
        first = seen.setdefault(folder.resolve(), folder)
        if first is not folder:
            raise _fail(folder, key, f"given twice (as {first})", "expected each folder once")
    return list(seen.values())


def working_folder_gone() -> bool:
    """Whether the process's working folder was deleted (``os.getcwd`` fails): a relative path
    then names nothing."""
    try:
        os.getcwd()
    except FileNotFoundError:
        return True
    return False


def need_working_folder(named: str, what: str, instead: str) -> None:
    """Refuse ``what`` (a stage that starts Hydra and torch, which need the working folder)
    when the working folder was deleted: ``<named>: ... ; ... or <instead>``."""
    if working_folder_gone():
        raise UssSlamError(
            f"{named}: the working folder no longer exists (it was deleted), and {what} needs "
            f"one (torch and Hydra cannot start without it); run from an existing folder, or "
            f"{instead}"
        )


def umask() -> int:
    """The process's file mode creation mask (``/proc/self/status``; else set and restored)."""
    try:
        with open("/proc/self/status", encoding="ascii") as status:
            for line in status:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def _umask_problem() -> str | None:
    """Why a folder created now could not be written into: the umask removes its owner's
    write or search permission (``umask 0222``), else None."""
    mask = umask()
    if mask & 0o300:
        return (
            f"a folder created now could not be written into: the umask {mask:04o} removes "
            "the owner's write permission; set a umask such as 0022"
        )
    return None


def _nearest_existing(path: Path) -> Path:
    probe = path
    while not os.path.lexists(probe) and probe != probe.parent:
        probe = probe.parent
    return probe


def _probe_write(folder: Path) -> str | None:
    """Create (and remove) a file in ``folder``: why that fails, else None."""
    try:
        with tempfile.TemporaryFile(dir=folder, prefix=".uss-slam-probe."):
            pass
    except OSError as error:
        return f"cannot write to {folder} ({error.strerror or type(error).__name__})"
    return None


def output_folder(
    path: str | PathLike[str],
    key: str | None = None,
    *,
    create: bool = False,
    expected: str = "expected a folder to write into",
    inputs: Iterable[tuple[str | None, str | PathLike[str]]] = (),
) -> Path:
    """A folder the script can write into (``create``: made now, with its parents; else only
    proved creatable: the nearest existing folder on the way can be written); else
    :class:`PathError`. An existing file, a dangling or looping link where the folder would be
    are refused, and so is one of the run's input folders (``inputs``: ``(key, folder)``, in
    any spelling): the outputs would be written among the inputs."""
    _not_empty(path, key, expected)
    path = Path(path)
    problem = structure_problem(path, folder=True, output=True)
    if problem is None:
        problem = _an_input(path, inputs)
    if problem is None:
        existing = _nearest_existing(path)
        if existing != path:
            problem = _umask_problem()
        if problem is None and create:
            try:
                path.mkdir(parents=True, exist_ok=True)
            except OSError as error:
                problem = f"cannot create it ({error.strerror or type(error).__name__})"
            existing = path
        if problem is None:
            problem = _probe_write(existing)
    if problem:
        raise _fail(path, key, problem, expected)
    output_keys.record(path, key)
    return path


def _not_empty(path: str | PathLike[str] | None, key: str | None, expected: str) -> None:
    """Refuse an empty output path (``out_dir=`` on a Hydra command line, ``''``, ``null``):
    ``Path('')`` is the working folder, into which the outputs would have gone."""
    if path is None or not str(path).strip():
        shown = "" if path is None else str(path)
        raise _fail(shown, key, "an empty path (it would be the working folder)", expected)


def _read_only(path: Path) -> bool:
    """Whether the file ``path`` may not be written: by this user, or by anyone (no write bit:
    ``chmod a-w``, which root could ignore but a user means)."""
    return not os.access(path, os.W_OK) or not os.stat(path).st_mode & 0o222


def _an_input(path: Path, inputs: Iterable[tuple[str | None, str | PathLike[str]]],
              kind: str = "folder") -> str | None:  # fmt: skip
    """Which input folder (or file) ``path`` is, resolved (as :func:`distinct_folders`
    compares; ``x/../gt.png`` too, while ``x`` does not exist), else None."""
    for key, given in inputs:
        if (os.path.isdir(given) if kind == "folder" else os.path.isfile(given)) and (
            os.path.realpath(path) == os.path.realpath(given)
        ):
            own = "a folder of its own for the outputs" if kind == "folder" else "a file of its own"
            return f"is the input {kind} {where(given, key)}; expected {own}"
    return None


def output_file(
    path: str | PathLike[str],
    key: str | None = None,
    expected: str = "expected a file to write",
    inputs: Iterable[tuple[str | None, str | PathLike[str]]] = (),
) -> Path:
    """A file the script can write (its folder existing or creatable, and writable); else
    :class:`PathError`. A folder, a dangling or looping link where the file would be are
    refused (a link to a file is written through, as ``open()`` does), and so is a path that
    ends with ``/`` (a folder's name) and one of the run's ``inputs`` (``(key, path)``: the
    output would replace it)."""
    _not_empty(path, key, expected)
    slash = getattr(path, "trailing_slash", False) or str(path).endswith("/")
    path = Path(path)
    problem = structure_problem(path, folder=False, output=True)
    if problem is None and slash:
        raise _fail(f"{path}/", key, "ends with '/', which names a folder", expected)
    if problem is None:
        problem = _an_input(path, inputs, "file")
    if problem is None and os.path.isfile(path) and _read_only(path):
        problem = "is read-only (its mode forbids writing; make it writable to replace it)"
    if problem is None and not os.path.lexists(path.parent):
        problem = _umask_problem()
    if problem is None:
        problem = _probe_write(_nearest_existing(path.parent))
    if problem:
        raise _fail(path, key, problem, expected)
    output_keys.record(path, key)
    return path


def read_text(
    path: str | PathLike[str], expected: str = "expected a text file", encoding: str = "utf-8"
) -> str:
    """The text of an input file, read whole; every problem one :class:`DataFormatError`
    naming the file: one that cannot be read (:func:`input_file`'s problems), and a byte the
    encoding does not allow, with its line and column (1-based) and the byte (a Latin-1 ``é``
    in a UTF-8 file, a PNG given as a trajectory). A UTF-8 byte-order mark (what Windows
    editors write first) is not part of the text."""
    checked = input_file(path, None, expected)
    try:
        data = checked.read_bytes()
    except OSError as error:
        raise PathError(path, None, f"cannot read it ({error.strerror}); {expected}") from None
    if encoding.replace("_", "-").lower() in ("utf-8", "utf8") and data.startswith(BOM):
        data = data[len(BOM) :]
    try:
        return data.decode(encoding)
    except UnicodeDecodeError as error:
        line = data.count(b"\n", 0, error.start) + 1
        column = error.start - (data.rfind(b"\n", 0, error.start) + 1) + 1
        byte = data[error.start]
        raise DataFormatError(
            path,
            f"not a text file: byte 0x{byte:02x} at column {column} is not "
            f"{encoding.upper()}; {expected}",
            line,
        ) from None


def read_yaml(path: str | PathLike[str], expected: str = "expected a YAML file") -> Any:
    """The data of a YAML input file (:func:`read_text`'s checks first); a syntax error, and a
    key given twice in one mapping (which YAML loaders keep the last of without a word), are
    one :class:`DataFormatError` naming the file and the line."""
    import yaml

    class _Loader(yaml.SafeLoader):
        def construct_mapping(self, node: Any, deep: bool = False) -> Any:
            seen: dict[Any, int] = {}
            for key_node, _ in node.value:
                key = self.construct_object(key_node, deep=True)
                line = key_node.start_mark.line + 1
                if key in seen:
                    raise DataFormatError(
                        path, f"the key {key!r} is given twice (first at line {seen[key]}); "
                        f"{expected}", line,
                    )  # fmt: skip
                seen[key] = line
            return super().construct_mapping(node, deep=deep)

    text = read_text(path, expected)
    try:
        return yaml.load(text, Loader=_Loader)  # noqa: S506 (a SafeLoader)
    except yaml.YAMLError as err:
        mark = getattr(err, "problem_mark", None)
        problem = getattr(err, "problem", None) or "syntax error"
        line = None if mark is None else mark.line + 1
        raise DataFormatError(path, f"not valid YAML ({problem})", line) from None


BOM = b"\xef\xbb\xbf"
"""The UTF-8 byte-order mark."""
ROOT_KEYS = ("root", "roots")
"""Keys of a data config that name input folders (one, or a list): every data set's."""


def config_roots(config: object, prefix: str) -> Iterator[tuple[str, str]]:
    """``(full key, folder)`` of every input folder a plain data config names (``root: DIR``,
    ``roots: [DIR, ...]`` at any depth); values not yet given (``???``, None) are skipped."""
    if isinstance(config, dict):
        for name, value in config.items():
            key = f"{prefix}.{name}"
            if name in ROOT_KEYS:
                values = value if isinstance(value, list) else [value]
                for folder in values:
                    if isinstance(folder, str) and folder and folder != "???":
                        yield key, folder
            else:
                yield from config_roots(value, key)
    elif isinstance(config, list):
        for index, item in enumerate(config):
            yield from config_roots(item, f"{prefix}[{index}]")


def input_roots(config: object, prefix: str) -> None:
    """Check every input folder a plain data config names (:func:`config_roots`, e.g.
    ``data.source.root``, ``data.target.roots``) with :func:`input_folder`, the error naming
    the full key; a value not yet given is left to the config's own check."""
    by_key: dict[str, list[str]] = {}
    for key, folder in config_roots(config, prefix):
        input_folder(folder, key)
        by_key.setdefault(key, []).append(folder)
    for key, folders in by_key.items():
        distinct_folders(folders, key)


@contextmanager
def naming_roots(config: object, prefix: str) -> Iterator[None]:
    """A reader's :class:`DataFormatError` about a file inside a folder the data config names
    (:func:`config_roots`), raised inside, becomes one line naming that key too:
    ``data.target.roots=<folder>: rgb.txt: not a TUM RGB-D sequence: ...``."""
    try:
        yield
    except Exception as error:  # the reader's own, or one a library wrapped
        found: BaseException | None = error
        while found is not None and not isinstance(found, DataFormatError):
            found = found.__cause__
        if not isinstance(found, DataFormatError) or getattr(found, "key", None) is not None:
            raise
        file = Path(found.path).absolute()
        holding = [(Path(folder).absolute(), key, folder)
                   for key, folder in config_roots(config, prefix)
                   if file == Path(folder).absolute() or Path(folder).absolute() in file.parents]  # fmt: skip
        if not holding:
            raise
        root, _, folder = max(holding, key=lambda h: len(h[0].parts))  # the innermost folder
        keys = ", ".join(dict.fromkeys(k for r, k, _ in holding if r == root))  # each key once
        line = "" if found.line is None else f", line {found.line}"
        inside = f"{file.relative_to(root).as_posix()}{line}: " if file != root else ""
        raise PathError(folder, keys, f"{inside}{found.detail}") from None


_PLAIN_OVERRIDE = re.compile(r"[A-Za-z0-9_\-./+@%]+")
"""Characters a Hydra override value may hold unquoted (its lexer refuses others: spaces,
non-ASCII letters, quotes, brackets, commas, ``=``)."""


def hydra_quoted(text: str) -> str:
    """``text`` as a Hydra override value that reads back as the same string: as it is when
    Hydra reads it unquoted as that string, else single-quoted with ``\\`` and ``'`` escaped
    (a path with spaces or non-ASCII letters: ``'/data/résumé 1'``)."""
    if _PLAIN_OVERRIDE.fullmatch(text) and not _typed(text):
        return text
    return "'" + text.replace("\\", "\\\\").replace("'", "\\'") + "'"


def _typed(text: str) -> bool:
    """True when Hydra would read ``text`` unquoted as a number, boolean or null."""
    if text.lower() in ("true", "false", "null"):
        return True
    try:
        float(text)
    except ValueError:
        return False
    return True


def path_override(key: str, value: str | PathLike[str] | list[str | PathLike[str]]) -> str:
    """The Hydra override ``key=<value>`` for a path (or a list of paths) one tool hands
    another (``uss-experiments`` and ``uss-demo`` to ``uss-train`` and ``uss-slam``), quoted
    where Hydra needs it (:func:`hydra_quoted`): a path valid for the user is valid there."""
    if isinstance(value, list):
        return f"{key}=[" + ",".join(hydra_quoted(os.fspath(v)) for v in value) + "]"
    return f"{key}={hydra_quoted(os.fspath(value))}"
