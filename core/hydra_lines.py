"""One line for an error of Hydra's composition of a config (a missing config group option,
an override that does not parse, a user's config file that is no valid YAML, OmegaConf's
errors) and for an output folder that cannot be created: the texts the Hydra apps' handler
(:mod:`uss_slam.core.cli`) prints."""

from __future__ import annotations

import contextlib
import errno
import io
import os
import sys
import warnings
from collections.abc import Iterator
from pathlib import Path

from uss_slam.core.errors import UssSlamError


def hydra_error_line(error: BaseException) -> str | None:
    """One line for an error Hydra raises while composing the config, naming the key; None for
    anything else. Built from the exceptions' attributes:

    - ``MissingConfigException`` (an unknown option of a config group): its ``missing_cfg_file``
      and ``options`` -> ``<group>: unknown option '<name>'; expected one of ...``;
    - ``OverrideParseException`` (bad override syntax): its ``override`` and the parser's
      ``message`` -> ``<override>: <message>`` (the message's first line: the second is Hydra's
      link to its grammar page);
    - an OmegaConf error in the cause chain (a value of the wrong type for a structured config,
      a key the config does not have): :func:`uss_slam.core.schema.omegaconf_error_line`,
      ``<key>: expected ..., got ...``.

    Hydra's other composition errors (``+key`` for a key that exists, ``~key`` for one that does
    not, a sweep without ``-m``) carry no attributes besides their text: their lines are joined
    into one, as the only part of this function that reads an error's text."""
    from hydra.errors import HydraException, MissingConfigException, OverrideParseException
    from omegaconf.errors import OmegaConfBaseException

    from uss_slam.core.schema import omegaconf_error_line

    chain: list[BaseException] = []
    current: BaseException | None = error
    while current is not None and all(current is not c for c in chain):
        chain.append(current)
        current = current.__cause__ or current.__context__
    for item in chain:
        line = _group_value_line(item)
        if line is not None:
            return line
        if isinstance(item, MissingConfigException) and item.missing_cfg_file:
            group, _, name = item.missing_cfg_file.rpartition("/")
            if item.options:
                expected = ", ".join(item.options)
                return f"{group}: unknown option {name!r}; expected one of {expected}"
            return f"{item.missing_cfg_file}: no such config"
        if isinstance(item, OverrideParseException):
            return override_parse_line(item.override, item.message)
        line = _yaml_error_line(item)
        if line is not None:  # a config file of the user's (--config-dir) that does not parse
            return line
    for item in chain:
        if isinstance(item, OmegaConfBaseException):
            return omegaconf_error_line(item)
    for item in chain:
        if isinstance(item, HydraException):
            lines = [line.strip().rstrip(".") for line in str(item).splitlines() if line.strip()]
            return "; ".join(lines) or type(item).__name__
    return None


def typed_overrides(hydra_config: object) -> list[str]:
    """The overrides of a Hydra job as typed (``hydra.overrides.task``, from Hydra's config):
    read item by item, OmegaConf would resolve an interpolation inside one (``x=${nope}``) and
    raise on a key the config does not have, before the job's own check names it."""
    from omegaconf import OmegaConf

    task = OmegaConf.select(hydra_config, "overrides.task", default=None)  # type: ignore[arg-type]
    if task is None:
        return []
    return [str(o) for o in OmegaConf.to_container(task, resolve=False)]  # type: ignore[union-attr]


HYDRA_ESCAPED = "\\()[]{}:=, \t"
"""The characters Hydra's sweeper escapes with a backslash in the unquoted values of each job's
overrides (``hydra.overrides.task``; ``escape_special_characters`` of its override grammar)."""


def as_typed(override: str) -> str:
    """A multirun job's override as the user typed it: the backslashes that Hydra's sweeper put
    before :data:`HYDRA_ESCAPED` outside quotes removed (``x=$\\{oops\\}`` -> ``x=${oops}``);
    a quoted value, which Hydra leaves as it was, unchanged."""
    out, quote, i = [], "", 0
    while i < len(override):
        char = override[i]
        if quote and char == "\\":  # inside quotes a backslash keeps the next character
            out.append(override[i : i + 2])
            i += 2
            continue
        if quote:
            quote = "" if char == quote else quote
        elif char in "'\"":
            quote = char
        elif char == "\\" and override[i + 1 : i + 2] and override[i + 1] in HYDRA_ESCAPED:
            i += 1
            char = override[i]
        out.append(char)
        i += 1
    return "".join(out)


def _group_value_line(error: BaseException) -> str | None:
    """``group=null`` (or a number, a mapping) for a config group: Hydra's ``ValueError``
    (``Config group override must be a string or a list. Got NoneType``) names no key; its
    override and the group's options are the locals of the frame that raised it."""
    if not isinstance(error, ValueError) or "Config group override" not in str(error):
        return None
    tb, found = error.__traceback__, None
    while tb is not None:
        if tb.tb_frame.f_globals.get("__name__") == "hydra._internal.defaults_list":
            found = tb.tb_frame.f_locals
        tb = tb.tb_next
    override = (found or {}).get("override")
    if override is None:
        return None
    group = override.key_or_group
    options = ", ".join(found["repo"].get_group_options(group)) if "repo" in found else ""
    expected = f"one of its options: {options}" if options else "one of its options by name"
    return f"{override.input_line}: {group} is a config group; expected {expected}"


def _yaml_error_line(error: BaseException) -> str | None:
    """``<file>:<line>: not valid YAML (<problem>)`` for PyYAML's error with a position."""
    import yaml

    mark = getattr(error, "problem_mark", None)
    if not isinstance(error, yaml.MarkedYAMLError) or mark is None:
        return None
    return f"{mark.name}:{mark.line + 1}: not valid YAML ({error.problem or 'syntax error'})"


def override_parse_line(override: str, message: str) -> str:
    """``<override>: <the parser's message>``; for a value holding characters Hydra reads only
    quoted (spaces, non-ASCII letters such as in ``out_dir=/data/résumé``), the quoted form to
    use instead of the lexer's text. One line: a control character (a newline in a folder's
    name) is written as Python writes it (:func:`uss_slam.core.errors.shown`)."""
    from uss_slam.core.errors import shown

    return shown(_override_parse_line(override, message))


def _override_parse_line(override: str, message: str) -> str:
    key, sep, value = override.partition("=")
    if sep and value.startswith("[") and value.endswith("]") and "=" in value:  # [a=1,b=2]
        return (f"{key}: a list item holding '=' must be quoted for Hydra; write "
                f"{key}={_quoted_items(value)}")  # fmt: skip
    if sep and value and not value.startswith(("'", '"', "[", "{")):
        from uss_slam.core.paths import hydra_quoted

        if value.startswith("~"):  # one the command line's expansion left: no such user
            return (
                f"{key}: the value {value!r} starts with '~', and this system has no user "
                f"{value[1:].split('/')[0]!r}; expected ~/..., ~USER/... or the path written out"
            )
        quoted = hydra_quoted(value)
        if quoted != value and any(ord(c) > 127 or c.isspace() for c in value):
            return (
                f"{key}: the value {value!r} must be quoted for Hydra (it holds spaces or "
                f'non-ASCII characters); write {key}={quoted} (in a shell: "{key}={quoted}")'
            )
        odd = sorted({c for c in value if c in "=()'\"\\:$*?<>|;&!#"})
        if quoted != value and odd:  # a folder named a=b or run(1): Hydra's grammar
            return (
                f"{key}: the value {value!r} must be quoted for Hydra (it holds "
                f'{" ".join(odd)}); write {key}={quoted} (in a shell: "{key}={quoted}")'
            )
    return f"{override}: {(message.strip().splitlines() or ['cannot be parsed'])[0]}"


def output_folder_line(error: OSError) -> str:
    """``cannot create the output folder <path> (<why>)`` for an ``OSError`` of ``mkdir``;
    names the file in the way when a part of the path is a file."""
    path = Path(str(error.filename))
    if error.errno == errno.ENAMETOOLONG:
        from uss_slam.core.files import check_name_lengths

        try:
            check_name_lengths(path)
        except UssSlamError as too_long:
            return f"cannot create the output folder {too_long}"
        return f"cannot create the output folder {path} (a name in it is too long)"
    existing = path
    while not existing.exists() and existing != existing.parent:
        existing = existing.parent
    if existing.exists() and not existing.is_dir():
        why = "it is a file" if existing == path else f"{existing} is a file"
    else:
        why = error.strerror or type(error).__name__
    return f"cannot create the output folder {path} ({why})"


def repeated_override_line(argv: list[str]) -> str | None:
    """One line for a key given twice on a Hydra app's command line (``uss-train a=1 a=2``:
    Hydra keeps the last value without a word), else None. The overrides are found by Hydra's
    own argument parser and override parser (a group, ``+key``, ``~key`` and a package
    ``group@pkg`` alike); a command line either cannot parse is left to Hydra's own error."""
    from hydra._internal.utils import get_args_parser

    if any(arg in ("--version", "--help", "-h", "--hydra-help") for arg in argv):
        return None  # they print and exit before any override is used
    try:
        args, _ = get_args_parser().parse_known_args(without_ddp_tail(argv))
    except (Exception, SystemExit):  # noqa: BLE001 (Hydra reports it itself)
        return None
    found = repeated_key(args.overrides or [])
    if found is None:
        return None
    key, first, second = found
    return (
        f"{key}: given twice on the command line ({first} and {second}); expected each key "
        "once (Hydra would keep the last one without a word)"
    )


DDP_TAIL = ("hydra.run.dir=", "hydra.job.name=train_ddp_process_", "hydra.output_subdir=null")
"""The overrides Lightning's DDP launcher appends to the command line of each process it starts
from a Hydra app (the parent's run folder, given again though the user may have set it)."""


def without_ddp_tail(argv: list[str]) -> list[str]:
    """``argv`` without the three overrides Lightning's DDP launcher appended (:data:`DDP_TAIL`),
    which repeat a key on purpose; the user's own overrides were checked in the parent."""
    tail = argv[-len(DDP_TAIL) :]
    if len(tail) == len(DDP_TAIL) and all(map(str.startswith, tail, DDP_TAIL)):
        return argv[: -len(DDP_TAIL)]
    return argv


def repeated_key(overrides: list[str]) -> tuple[str, str, str] | None:
    """``(key, first, second)`` of the first key that ``overrides`` (Hydra overrides, read by
    Hydra's own override parser) set twice, else None (also when they do not parse: Hydra's
    own error then says why)."""
    from hydra.core.override_parser.overrides_parser import OverridesParser

    try:
        parsed = OverridesParser.create().parse_overrides([str(o) for o in overrides])
    except Exception:  # noqa: BLE001
        return None
    seen: dict[str, str] = {}
    for override in parsed:
        key = override.key_or_group + (f"@{override.package}" if override.package else "")
        line = override.input_line or key
        if key in seen:
            return key, seen[key], line
        seen[key] = line
    return None


SWITCHES = (("experimental_rerun", "--experimental-rerun"), ("shell_completion",
            "--shell-completion"), ("info", "--info"), ("cfg", "--cfg"), ("package", "--package"),
            ("config_dir", "--config-dir"), ("config_path", "--config-path"),
            ("config_name", "--config-name"), ("resolve", "--resolve"))  # fmt: skip
"""Hydra's own switches (its argument parser's ``dest`` and flag), most particular first (the
one Hydra's text names is named, where it names one given)."""


def hydra_switch_line(error: BaseException, argv: list[str]) -> str | None:
    """One line for an error raised by Hydra's own code before any job started (a switch it
    cannot follow: ``--experimental-rerun`` of a missing file, ``--shell-completion`` without
    ``install=SHELL``), naming the switch; None for an error raised elsewhere (an internal
    error keeps its traceback)."""
    from hydra._internal.utils import get_args_parser

    tb = error.__traceback__
    while tb is not None and tb.tb_next is not None:
        tb = tb.tb_next
    module = "" if tb is None else str(tb.tb_frame.f_globals.get("__name__", ""))
    if module.split(".")[0] != "hydra":
        return None
    text = (str(error).strip().splitlines() or [type(error).__name__])[0].rstrip("!. ")
    try:
        args, _ = get_args_parser().parse_known_args(argv)
    except (Exception, SystemExit):  # noqa: BLE001
        return text
    given = [(flag, getattr(args, dest)) for dest, flag in SWITCHES if getattr(args, dest, None)]
    named = [(flag, value) for flag, value in given if flag in text] or given
    if not named:
        return text
    flag, value = named[0]
    return f"{flag if value is True else f'{flag}={value}'}: {text}"


def _hydra_args(argv: list[str]) -> object | None:
    """``argv`` read by Hydra's own argument parser, or None when it cannot be."""
    from hydra._internal.utils import get_args_parser

    try:
        return get_args_parser().parse_known_args(without_ddp_tail(argv))[0]
    except (Exception, SystemExit):  # noqa: BLE001 (Hydra reports it itself)
        return None


MAX_CONFIG_FILES = 2000
"""Config files of a ``--config-dir`` looked at for a hidden ``# @package`` line."""


def hidden_package_header(folder: Path) -> Path | None:
    """The first config file under ``folder`` (``--config-dir``) that starts with a UTF-8
    byte-order mark before a ``# @package`` header: Hydra reads the header from the file's
    first comment lines, and the mark (what Windows editors write first) hides it, so the
    config lands under its group without a word (YAML itself skips the mark)."""
    from uss_slam.core.paths import BOM

    for path in sorted(folder.rglob("*.yaml"))[:MAX_CONFIG_FILES]:
        try:
            with open(path, "rb") as fh:
                head = fh.read(4096)
        except OSError:
            continue  # Hydra names a file it cannot read
        if not head.startswith(BOM):
            continue
        for line in head[len(BOM) :].decode("utf-8", "replace").splitlines():
            if not line.startswith("#"):
                break
            if line[1:].strip().startswith("@package"):
                return path
    return None


@contextlib.contextmanager
def hydra_switch_texts(prog: str, argv: list[str]) -> Iterator[None]:
    """Hydra's own texts about its switches as the project's lines, around a Hydra app's run:

    - ``--experimental-rerun FILE``: Hydra's ``UserWarning`` that the option is experimental
      (printed before any error line) is dropped; overrides given beside it, which Hydra
      ignores, are one warning line naming them;
    - ``--cfg job --package KEY`` of a key the config does not have: Hydra's bare
      ``package 'KEY' not found in config`` is ``<prog>: error: --package=KEY: ...``;
      ``--package`` without ``--cfg``, which Hydra ignores (the run went on), is refused;
    - ``--config-dir`` is checked by the path layer (a file, a missing folder, a link loop)."""
    args = _hydra_args(argv)
    if getattr(args, "config_dir", None):  # the path layer's line (Hydra's: "not found")
        from uss_slam.core.paths import PathError, input_folder

        try:
            input_folder(args.config_dir, "--config-dir", "expected a folder of config files")  # type: ignore[attr-defined]
        except PathError as error:
            print(f"{prog}: error: {error}", file=sys.stderr)
            raise SystemExit(1) from None
        hidden = hidden_package_header(Path(args.config_dir))  # type: ignore[attr-defined]
        if hidden is not None:
            print(f"{prog}: error: {hidden}:1: starts with a UTF-8 byte-order mark, which hides "
                  "its '# @package' line from Hydra (the config would land under its group); "
                  "save the file without it", file=sys.stderr)  # fmt: skip
            raise SystemExit(1)
    rerun, package = getattr(args, "experimental_rerun", None), getattr(args, "package", None)
    overrides = list(getattr(args, "overrides", None) or [])
    with warnings.catch_warnings():
        if rerun:
            for text in ("Experimental rerun CLI option", "Config overrides are not supported"):
                warnings.filterwarnings("ignore", message=text, category=UserWarning)
            if overrides and os.path.isfile(rerun):
                print(f"{prog}: warning: {', '.join(overrides)}: set but change nothing with "
                      f"--experimental-rerun (the recorded config runs as it was)",
                      file=sys.stderr)  # fmt: skip
        if package and not any(getattr(args, k, None) for k in ("cfg", "help", "hydra_help")):
            print(f"{prog}: error: --package={package}: only used with --cfg, to print that "
                  f"part of the config (--cfg job --package {package}); without it the run "
                  "would ignore it", file=sys.stderr)  # fmt: skip
            raise SystemExit(1)
        if not (package and getattr(args, "cfg", None)):
            yield
            return
        caught = io.StringIO()
        try:
            with contextlib.redirect_stderr(caught):
                yield
        except SystemExit as stop:
            if stop.code not in (0, None) and caught.getvalue().startswith("package '"):
                caught = io.StringIO()
                print(f"{prog}: error: --package={package}: not found in the config; expected "
                      f"a key of it (--cfg {args.cfg} without --package prints them)",  # type: ignore[attr-defined]
                      file=sys.stderr)  # fmt: skip
                raise SystemExit(1) from None
            raise
        finally:
            sys.stderr.write(caught.getvalue())


VALUE_SWITCHES = ("--config-path", "-cp", "--config-name", "-cn", "--experimental-rerun",
                  "--package", "-p", "--cfg", "-c")  # fmt: skip
"""Hydra's switches whose next word is their value (not an override)."""


def home_expanded_argv(argv: list[str]) -> list[str]:
    """A Hydra app's command line with a ``~`` or ``~user`` starting a value expanded as a shell
    expands it (:func:`uss_slam.core.paths.home_expanded`), in every override (``key=~/x``,
    quoted ``key='~/x'``, the items of ``key=[~/a,~/b]``) and in ``--config-dir``: bash leaves
    ``--config-dir=~/c``, a quoted value and ``sh``'s ``key=~/x`` as they are, and Hydra's lexer
    refuses an unquoted ``~`` in a value. An expanded value is quoted where Hydra needs it."""
    from uss_slam.core.paths import home_expanded

    out: list[str] = []
    for arg in argv:
        previous = out[-1] if out else ""
        if previous in ("--config-dir", "-cd"):
            arg = home_expanded(arg)
        elif arg.startswith("--config-dir="):
            arg = "--config-dir=" + home_expanded(arg.partition("=")[2])
        elif not arg.startswith("-") and previous not in VALUE_SWITCHES and "=" in arg:
            key, _, value = arg.partition("=")
            bracketed = value.startswith("[") and value.endswith("]")
            inner = value[1:-1] if bracketed else value
            if bracketed or (value[:1] not in "'\"" and "," in value):  # a list, a sweep
                inner = ",".join(_home_expanded_value(i) for i in inner.split(","))
                arg = f"{key}=[{inner}]" if bracketed else f"{key}={inner}"
            else:
                arg = f"{key}={_home_expanded_value(value)}"
        out.append(arg)
    return out


def list_items_quoted_argv(argv: list[str]) -> list[str]:
    """A Hydra app's command line, ``~`` expanded (:func:`home_expanded_argv`), with the items
    of a list override that hold ``=`` quoted
    (``train.overrides=[model.max_iters=5,logger=none]`` ->
    ``train.overrides=['model.max_iters=5','logger=none']``): Hydra's grammar reads ``=`` only
    quoted, so the unquoted form has no other meaning; the keys that take such lists
    (``train.overrides``, ``slam.overrides``, ...) hold overrides of another script. Left as
    typed where it parses already, where an item holds quotes or brackets, or where the quoted
    form does not parse either (the parse error's line then says what to write)."""
    return [_list_items_quoted(arg) for arg in home_expanded_argv(argv)]


def _list_items_quoted(arg: str) -> str:
    key, sep, value = arg.partition("=")
    if arg.startswith("-") or not (sep and value[:1] == "[" and value[-1:] == "]"):
        return arg
    items = value[1:-1].split(",")
    if "=" not in value[1:-1] or any(set(i) & set("'\"[]{}") for i in items):
        return arg
    from hydra.core.override_parser.overrides_parser import OverridesParser
    from hydra.errors import OverrideParseException

    parser = OverridesParser.create()
    for candidate in (arg, f"{key}={_quoted_items(value)}"):
        try:
            parser.parse_overrides([candidate])
        except OverrideParseException:
            continue
        return candidate
    return arg


def _quoted_items(value: str) -> str:
    """``[a=1,b=2]`` -> ``['a=1','b=2']``: each item of a typed list quoted for Hydra."""
    from uss_slam.core.paths import hydra_quoted

    return "[" + ",".join(hydra_quoted(i.strip()) for i in value[1:-1].split(",")) + "]"


def _home_expanded_value(value: str) -> str:
    """One override value (unquoted or quoted) with a starting ``~`` expanded; as it is when
    there is none, or the user is unknown (the path layer's line then names the key)."""
    from uss_slam.core.paths import home_expanded, hydra_quoted

    quote = value[:1] if value[:1] in "'\"" and len(value) > 1 and value[-1] == value[0] else ""
    inner = value[1:-1] if quote else value
    expanded = home_expanded(inner)
    return value if expanded == inner else hydra_quoted(expanded)


@contextlib.contextmanager
def adding_refused_over_any_key() -> Iterator[None]:
    """``+key=value`` refused for every key the config already has, around a Hydra app's run.

    Hydra refuses ``+key=`` over a key with a value (``Could not append to config. An item is
    already at 'key'``, with the ``key=`` and ``++key=`` to write instead) but takes it over a
    key whose value is null or ``???`` and merges a list or mapping value into one (``+name=q``,
    ``+stages=[data]``): the same text for those, so every key refuses the ``+`` alike. The
    overrides are applied in their order, so ``~key +key=value`` still replaces a section."""
    from hydra._internal.config_loader_impl import ConfigLoaderImpl
    from hydra.errors import ConfigCompositionException

    original = ConfigLoaderImpl.__dict__["_apply_overrides_to_config"]
    apply = original.__func__

    def each_in_turn(overrides: list, cfg: object) -> None:
        for override in overrides:
            if override.is_add() and _has_key(cfg, override.key_or_group):
                key, line = override.key_or_group, override.input_line
                raise ConfigCompositionException(
                    f"Could not append to config. An item is already at '{key}'.\n"
                    f"Either remove + prefix: '{line[1:]}'\n"
                    f"Or add a second + to add or override '{key}': '+{line}'"
                )
            apply([override], cfg)

    ConfigLoaderImpl._apply_overrides_to_config = staticmethod(each_in_turn)  # type: ignore[method-assign]
    try:
        yield
    finally:
        ConfigLoaderImpl._apply_overrides_to_config = original  # type: ignore[method-assign]


def _has_key(cfg: object, key: str) -> bool:
    """Whether ``cfg`` holds ``key`` (dotted), whatever its value (null and ``???`` included)."""
    from omegaconf import DictConfig, OmegaConf

    parent_key, _, last = key.rpartition(".")
    parent = OmegaConf.select(cfg, parent_key, throw_on_missing=False) if parent_key else cfg  # type: ignore[arg-type]
    return isinstance(parent, DictConfig) and last in list(parent)  # ``in`` omits ??? keys


def empty_sweep_line(config: object) -> str | None:
    """A multirun whose sweep has no value (``-m 'slam.workers=range(0)'``, ``'segmenter=glob(zz*)'``):
    Hydra would launch no job, exit 0 and leave a sweep folder with only its ``multirun.yaml``.
    The line naming the first such override, read as Hydra's sweeper reads it (its own parser,
    with the config loader that expands a ``glob`` over a group's options), else None."""
    from hydra.core.global_hydra import GlobalHydra
    from hydra.core.override_parser.overrides_parser import OverridesParser
    from hydra.core.override_parser.types import ValueType
    from omegaconf import OmegaConf

    if not GlobalHydra.instance().is_initialized():
        return None
    hydra_config = OmegaConf.select(config, "hydra")  # type: ignore[arg-type]
    params = OmegaConf.select(hydra_config, "sweeper.params", default=None) or {}
    typed = [f"{k}={v}" for k, v in params.items()] + typed_overrides(hydra_config)
    loader = GlobalHydra.instance().config_loader()
    for override in OverridesParser.create(config_loader=loader).parse_overrides(typed):
        if override.is_discrete_sweep() and not list(override.sweep_string_iterator()):
            key = override.get_key_element()
            options = ""
            if override.value_type == ValueType.GLOB_CHOICE_SWEEP:
                names = loader.get_group_options(override.key_or_group)
                options = f" (the options of {key}: {', '.join(names)})" if names else ""
            text = override.input_line or key
            return (f"{text}: the sweep has no value, so a multirun would start no job; "
                    f"expected at least one value{options}")  # fmt: skip
    return None
