"""Typed config schemas (``uss_slam.core.schema``): one line ``<key>: expected ..., got ...``."""

from __future__ import annotations

import enum
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Annotated, Any, Literal, Optional

import pytest
from omegaconf import OmegaConf

from uss_slam.core.errors import UssSlamError
from uss_slam.core.schema import (
    Range,
    SchemaError,
    check,
    check_targets,
    describe,
    ranged,
    register,
    target_schema,
    validate,
)


class Align(enum.Enum):
    se3 = "se3"
    sim3 = "sim3"


@dataclass
class Inner:
    n: int = ranged(3, min=1)
    xs: list[int] = field(default_factory=lambda: [1])


@dataclass
class Section:
    count: int = 1
    rate: Optional[float] = ranged(None, gt=0, lt=1)  # noqa: UP045 (OmegaConf reads Optional)
    align: Align = Align.se3
    inner: Inner = field(default_factory=Inner)
    flag: bool = True
    mode: Any = ranged("a", choices=("a", "b", 3))
    name: str = ranged("run", text=True)
    label: str = "x"


@pytest.mark.parametrize(
    ("values", "line"),
    [
        ({"count": "abc"}, "sec.count: expected an integer, got 'abc'"),
        ({"count": "3"}, "sec.count: expected an integer, got '3'"),  # OmegaConf would convert
        ({"count": True}, "sec.count: expected an integer, got True"),
        ({"count": 2.5}, "sec.count: expected an integer, got 2.5"),
        ({"flag": 1}, "sec.flag: expected true or false, got 1"),
        ({"rate": "x"}, "sec.rate: expected a number > 0 and < 1 or null, got 'x'"),
        ({"rate": 1.0}, "sec.rate: expected a number > 0 and < 1 or null, got 1.0"),
        ({"rate": float("nan")}, "sec.rate: expected a finite number, got nan"),
        ({"align": "se4"}, "sec.align: expected one of se3, sim3, got 'se4'"),
        ({"mode": "c"}, "sec.mode: expected one of 'a', 'b', 3, got 'c'"),
        ({"mode": "3"}, "sec.mode: expected one of 'a', 'b', 3, got '3'"),
        ({"inner": {"n": 0}}, "sec.inner.n: expected an integer >= 1, got 0"),
        ({"inner": {"n": "q"}}, "sec.inner.n: expected an integer >= 1, got 'q'"),
        ({"inner": {"xs": [1, "z"]}}, "sec.inner.xs[1]: expected an integer, got 'z'"),
        ({"inner": 3}, "sec.inner: expected a mapping of Inner's keys, got 3"),
        ({"label": 5}, "sec.label: expected a string, got 5"),
        ({"bogus": 1}, "sec.bogus: unknown key; expected one of count, rate, align, inner, flag, "
                       "mode, name, label"),
        ({"inner": {"m": 1}}, "sec.inner.m: unknown key; expected one of n, xs"),
    ],
)  # fmt: skip
def test_validate_names_the_key_and_what_was_expected(values: dict, line: str) -> None:
    with pytest.raises(SchemaError) as caught:
        validate(OmegaConf.create(values), Section, "sec")
    assert str(caught.value) == line
    assert isinstance(caught.value, UssSlamError) and "\n" not in str(caught.value)


def test_validate_returns_the_typed_object() -> None:
    cfg = OmegaConf.create({"sec": {"rate": "${half}", "align": "sim3", "inner": {"n": 2}},
                            "half": 0.5})  # fmt: skip
    settings = validate(cfg.sec, Section, "sec")
    assert settings == Section(rate=0.5, align=Align.sim3, inner=Inner(n=2))
    assert validate({"name": 2024}, Section).name == "2024"  # a name may be a number
    assert validate(None, Section) == Section()


def test_a_required_value_left_open_is_named() -> None:
    @dataclass
    class Needs:
        path: str = "???"

    with pytest.raises(SchemaError, match=r"^path: expected a string \(no value was given\)$"):
        validate({}, Needs)


def test_describe() -> None:
    assert describe(Optional[int], {"min": 1}) == "an integer >= 1 or null"  # noqa: UP045
    assert describe(list[str]) == "a list of strings"
    assert describe(Literal[1, "a"]) == "one of 1, 'a'"
    assert describe(Align) == "one of se3, sim3"
    assert describe(list[Align], {"nonempty": True}) == "a non-empty list of se3, sim3"
    assert describe(list[int], {"min": 0, "nonempty": True}) == (
        "a non-empty list of integers >= 0"
    )


def test_a_list_fields_bounds_are_each_elements() -> None:
    @dataclass
    class Grid:
        depths: list[int] = ranged(default_factory=lambda: [4], min=1, max=8, nonempty=True)
        seeds: list[Align] = field(default_factory=lambda: [Align.se3])

    assert validate({"depths": [1, 8]}, Grid).depths == [1, 8]
    for values, line in [
        ({"depths": [4, 9]}, "depths[1]: expected an integer >= 1 and <= 8, got 9"),
        ({"depths": [4, "x"]}, "depths[1]: expected an integer >= 1 and <= 8, got 'x'"),
        ({"depths": []}, "depths: expected a non-empty list of integers >= 1 and <= 8, got []"),
        ({"depths": "x"}, "depths: expected a non-empty list of integers >= 1 and <= 8, got 'x'"),
        ({"seeds": ["se3", "se9"]}, "seeds[1]: expected one of se3, sim3, got 'se9'"),
    ]:
        with pytest.raises(SchemaError) as caught:
            validate(values, Grid)
        assert str(caught.value) == line


def test_register_puts_an_editable_schema_in_the_config_store() -> None:
    from hydra.core.config_store import ConfigStore

    @dataclass(frozen=True)
    class Frozen:
        inner: Inner = field(default_factory=Inner)

    register("test_schema_group", "frozen", Frozen)
    node = ConfigStore.instance().load("test_schema_group/frozen.yaml").node
    node.inner.n = 5  # writable, still typed
    with pytest.raises(Exception, match="could not be converted"):
        node.inner.n = "many"


def _target(
    count: int,
    rate: float = 0.1,
    names: Sequence[str] = (),
    precision: Literal[16, 32, "bf16"] = 32,
    betas: tuple[float, float] = (0.9, 0.99),
    anything: str | object = "",
    lr: float | Enum = 0.1,  # noqa: F821 (an opaque class, dropped from the union)
) -> None:
    """A stand-in target for the node checks."""


class Enum:  # the "opaque" class of _target's lr (a class config values never are)
    pass


def test_target_schema_from_annotations() -> None:
    schema = target_schema(_target, opaque=(Enum,))
    assert schema is not None
    assert target_schema("no.such.Thing") is None  # left to Hydra when it builds it
    node = OmegaConf.create({"count": 2, "names": ["x", 3], "anything": 3})
    with pytest.raises(SchemaError, match=r"^m\.names\[1\]: expected a string, got 3$"):
        check(node, schema, "m")


@pytest.mark.parametrize(
    ("node", "line"),
    [
        ({"count": "many"}, "m.count: expected an integer, got 'many'"),
        ({"precision": "32"}, "m.precision: expected one of 16, 32, 'bf16', got '32'"),
        ({"betas": [0.9]}, "m.betas: expected a list of numbers of length 2, got [0.9]"),
        ({"lr": "fast"}, "m.lr: expected a number, got 'fast'"),
        ({"rates": 1}, f"m.rates: unknown key; expected one of count, rate, names, precision, "
                       f"betas, anything, lr (the parameters of {__name__}._target)"),
    ],
)  # fmt: skip
def test_check_targets_names_the_key(node: dict, line: str) -> None:
    cfg = OmegaConf.create({"m": {"_target_": f"{__name__}._target", **node}})
    with pytest.raises(SchemaError) as caught:
        check_targets(cfg, ["m"], opaque=(Enum,))
    assert str(caught.value) == line


def test_check_targets_recurses_and_leaves_what_it_cannot_judge() -> None:
    target = f"{__name__}._target"
    nested = OmegaConf.create({"m": {"list": [{"_target_": target, "count": "many"}]}})
    with pytest.raises(SchemaError, match=r"^m\.list\[0\]\.count: expected an integer"):
        check_targets(nested, ["m"])
    fine = OmegaConf.create(
        {
            "m": {
                "_target_": target,
                "count": "???",
                "rate": "${r}",
                "anything": {"a": 1},
                "names": {"_target_": "builtins.list"},
            },
            "r": 1,
        }  # fmt: skip
    )
    check_targets(fine, ["m", "absent"])  # ??? left to Hydra, the interpolation resolved
    check_targets(OmegaConf.create({"m": {"_target_": "no.such.Thing", "x": 1}}), ["m"])
    also = OmegaConf.create({"m": {"_target_": target, "count": 1, "precision": "auto"}})
    check_targets(also, ["m"], also={"m.precision": ("auto",)})


def test_hydra_error_line_from_the_exceptions_attributes(tmp_path) -> None:
    from hydra import compose, initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra

    from uss_slam.core.cli import hydra_error_line

    register("test_schema_group", "section", Section)
    (tmp_path / "g").mkdir()
    (tmp_path / "g" / "a.yaml").write_text("x: 1\n")
    (tmp_path / "g" / "b.yaml").write_text("x: 2\n")
    (tmp_path / "main.yaml").write_text(
        "defaults:\n  - g: a\n  - /test_schema_group/section@sec\n  - _self_\nlimit: 3\n"
    )

    def line(*overrides: str) -> str | None:
        GlobalHydra.instance().clear()
        try:
            with initialize_config_dir(config_dir=str(tmp_path), version_base="1.3"):
                compose("main", overrides=list(overrides))
        except Exception as error:
            return hydra_error_line(error)
        finally:
            GlobalHydra.instance().clear()
        return "composed"

    assert line("g=b") == "composed"
    assert line("g=c") == "g: unknown option 'c'; expected one of a, b"
    assert line("limit=[1") == "limit=[1: no viable alternative at input '[1'"
    assert line("sec.count=many") == "sec.count: expected an integer, got 'many'"
    assert line("sec.align=se4") == "sec.align: expected one of se3, sim3, got 'se4'"
    assert line("sec.inner.nn=1") == "sec.inner.nn: unknown key; expected one of n, xs"
    assert line("limits=4") == "limits: unknown key; expected one of g, sec, limit"
    # no structured form: Hydra's text, its lines joined
    assert line("+limit=4") == (
        "Could not append to config. An item is already at 'limit'; "
        "Either remove + prefix: 'limit=4'; Or add a second + to add or override 'limit': "
        "'++limit=4'"
    )
    assert hydra_error_line(ValueError("not Hydra's")) is None


@dataclass
class _Weights:
    """A dataclass target whose fields declare their ranges (as train.losses.LossWeights)."""

    weight: float = ranged(0.5, min=0)
    name: str = "w"


def test_a_dataclass_targets_declared_ranges_are_checked() -> None:
    cfg = OmegaConf.create({"loss": {"_target_": f"{__name__}._Weights", "weight": -1}})
    with pytest.raises(SchemaError) as caught:
        check_targets(cfg, ["loss"])
    assert str(caught.value) == "loss.weight: expected a number >= 0, got -1"
    check_targets(OmegaConf.create({"loss": {"_target_": f"{__name__}._Weights", "weight": 0}}),
                  ["loss"])  # fmt: skip


def test_lists_of_names_take_each_item_once_and_vectors_may_repeat() -> None:
    @dataclass
    class Lists:
        names: list[str] = field(default_factory=list)
        mean: list[float] = field(default_factory=list)
        seeds: list[int] = ranged(default_factory=list, unique=True)

    assert validate({"names": ["a", "b"], "mean": [0.5, 0.5]}, Lists).mean == [0.5, 0.5]
    with pytest.raises(SchemaError) as info:
        validate({"names": ["a", "b", "a"]}, Lists, "sec")
    assert str(info.value) == (
        "sec.names: expected a list of strings, each once ('a' is listed twice), got ['a', 'b', 'a']"
    )
    with pytest.raises(SchemaError, match=r"^seeds: expected a list of integers, each once \(1 is"):
        validate({"seeds": [1, 1]}, Lists)


def test_settings_objects_check_themselves_and_errors_move_into_their_section() -> None:
    from uss_slam.core.schema import check_fields

    @dataclass(frozen=True)
    class Settings:
        n: int = ranged(1, min=1)

        def __post_init__(self) -> None:
            check_fields(self)

    with pytest.raises(SchemaError) as info:
        Settings(n=0)
    assert str(info.value) == "n: expected an integer >= 1, got 0"
    assert str(info.value.within("slam.x")) == "slam.x.n: expected an integer >= 1, got 0"


def _annotated(count: Annotated[int, Range(min=2)] = 3, rate: float = 0.1) -> None:
    """A stand-in target whose range is in its annotation."""


def test_annotated_and_declared_ranges_of_targets() -> None:
    from uss_slam.core.schema import declare

    target = f"{__name__}._annotated"
    declare(target, rate=Range(gt=0, lt=1))
    with pytest.raises(SchemaError, match=r"^f\.count: expected an integer >= 2, got 1$"):
        check_targets(OmegaConf.create({"f": {"_target_": target, "count": 1}}), ["f"])
    with pytest.raises(SchemaError, match=r"^f\.rate: expected a number > 0 and < 1, got 1\.5$"):
        check_targets(OmegaConf.create({"f": {"_target_": target, "rate": 1.5}}), ["f"])


@dataclass
class Switched:
    on: bool = False
    level: int = ranged(3, needs="on")


@dataclass
class Outer:
    inner: Switched = field(default_factory=Switched)


def test_a_setting_that_needs_a_switch_that_is_off_is_named() -> None:
    from uss_slam.core.schema import unused_settings

    assert unused_settings({"inner": {"on": False, "level": 3}}, Outer) == []
    assert unused_settings({"inner": {"on": True, "level": 4}}, Outer) == []
    assert unused_settings({"inner": {"on": False, "level": 4}}, Outer) == [
        "inner.level is set but changes nothing while inner.on is false"
    ]


def test_generated_bad_values_cover_every_kind() -> None:
    from uss_slam.core.schema.cases import bad_values

    @dataclass
    class Gen:
        n: int = ranged(1, min=1, max=9)
        names: list[str] = ranged(default_factory=lambda: ["a"], nonempty=True)
        mode: str = ranged("x", choices=("x", "y"))

    found = {(b.key, b.kind, repr(b.value)) for b in bad_values(Gen, "g")}
    assert found == {
        ("g.no_such_key", "unknown", "1"),
        ("g.n", "empty", "None"), ("g.n", "type", "'abc'"), ("g.n", "range", "0"),
        ("g.n", "range", "10"),
        ("g.names", "empty", "None"), ("g.names", "type", "'abc'"), ("g.names", "empty", "[]"),
        ("g.names", "duplicate", "['a', 'a']"),
        ("g.mode", "empty", "None"), ("g.mode", "range", "'no_such_choice'"),
    }  # fmt: skip
    for b in bad_values(Gen, "g"):
        with pytest.raises(SchemaError, match=rf"^{b.key}"):
            validate({b.key.split(".")[1]: b.value}, Gen, "g")


def test_a_rules_other_key_gets_the_section_too() -> None:
    """``min_fast <= ini_fast`` raised inside ``slam.orb``'s settings names both full keys."""
    from uss_slam.core.schema import SchemaError

    error = SchemaError("min_fast", "an integer <= {ini_fast} (5)", 20)
    assert str(error) == "min_fast: expected an integer <= ini_fast (5), got 20"
    assert str(error.within("slam.orb")) == (
        "slam.orb.min_fast: expected an integer <= slam.orb.ini_fast (5), got 20"
    )


def test_an_integer_without_a_bound_of_its_own_fits_a_c_int() -> None:
    """A count past 2**31 - 1 is no run that ends, and the libraries take it as a C int:
    refused by the one rule, naming the bound, whatever the key."""
    from uss_slam.core.schema.checking import C_INT_MAX

    @dataclass
    class Counts:
        iterations: int = ranged(100, min=1)
        offset: int = 0
        capped: int = ranged(5, max=10)

    check({"iterations": C_INT_MAX, "offset": -C_INT_MAX - 1}, Counts, "x")
    with pytest.raises(
        UssSlamError,
        match=r"^x\.iterations: expected an integer >= 1 and <= 2147483647, got 2147483648$",
    ):
        check({"iterations": C_INT_MAX + 1}, Counts, "x")
    with pytest.raises(UssSlamError, match=r"^x\.offset: expected an integer >= -2147483648"):
        check({"offset": -(2**40)}, Counts, "x")
    with pytest.raises(
        UssSlamError, match=r"^x\.capped: expected an integer <= 10, got 2147483648"
    ):
        check({"capped": 2**31}, Counts, "x")  # its own bound speaks


def test_a_users_config_file_that_is_no_yaml_is_one_line(tmp_path) -> None:
    import yaml

    from uss_slam.core.cli import hydra_error_line

    mine = tmp_path / "mine.yaml"
    mine.write_text("path: /x\nmax_frames: [10\n")
    try:
        with mine.open() as stream:
            yaml.safe_load(stream)
    except yaml.YAMLError as error:
        line = hydra_error_line(RuntimeError("Hydra's wrapper").with_traceback(None))
        assert line is None
        wrapped = RuntimeError("Hydra's wrapper")
        wrapped.__cause__ = error
        assert hydra_error_line(wrapped) == (
            f"{mine}:3: not valid YAML (expected ',' or ']', but got '<stream end>')"
        )


@dataclass
class _Typed:
    flag: bool = True
    count: int = 2
    scale: float = 1.0
    inner: _Typed | None = None
    name: str = "x"


@pytest.mark.parametrize(
    ("override", "key", "expected"),
    [
        ("flag=no", "flag", "flag: expected true or false, got 'no'"),
        ("flag=off", "flag", "flag: expected true or false, got 'off'"),
        ("flag=1", "flag", "flag: expected true or false, got 1"),
        ("count='3'", "count", "count: expected an integer, got '3'"),
        ("scale=true", "scale", "scale: expected a number, got True"),
        ("scale=inf", "scale", "scale: expected a finite number, got inf"),
        ("scale=nan", "scale", "scale: expected a finite number, got nan"),
        ("inner.flag=yes", "inner.flag", "inner.flag: expected true or false, got 'yes'"),
    ],
)
def test_a_typed_configs_command_line_values_are_checked_as_written(
    override: str, key: str, expected: str
) -> None:
    """A config typed while Hydra composes it has ``no`` as false already; the command line
    says what the user wrote, and it is refused as the schemas checked later refuse it."""
    from uss_slam.core.schema import check_overrides_written

    cfg = OmegaConf.structured(_Typed(inner=_Typed()))
    with pytest.raises(SchemaError) as err:
        check_overrides_written(cfg, [override])
    assert str(err.value).startswith(expected), str(err.value)
    assert err.value.key == key


@pytest.mark.parametrize(
    "override",
    ["flag=false", "flag=true", "count=3", "scale=2", "scale=0.5", "name=no", "name=1",
     "flag=${inner.flag}", "+other=1", "~inner", "flag=true,false"],
)  # fmt: skip
def test_values_written_as_their_type_and_the_rest_pass(override: str) -> None:
    from uss_slam.core.schema import check_overrides_written

    check_overrides_written(OmegaConf.structured(_Typed(inner=_Typed())), [override])


def test_uss_slam_refuses_no_for_a_boolean_key() -> None:
    from shared_helpers import compose_slam_eval

    from uss_slam.slam_eval.config import check

    overrides = ["slam.loop_closing=no"]
    with pytest.raises(SchemaError, match=r"^slam\.loop_closing: expected true or false, got 'no'"):
        check(compose_slam_eval(overrides), overrides)
