"""The one YAML reader (drill_env.yamlio): YAML 1.2 numbers and booleans, duplicate keys
refused naming the key and its lines, nesting, size and numbers bounded; every option that
reads YAML ends with exit code 2 and one line ``error: ...`` for such a file, never a
traceback. A property-based fuzzer feeds random YAML to every such option."""

from __future__ import annotations

import math
import string
from pathlib import Path

import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

import drill_env
from drill_env.cli import app
from drill_env.params import ParameterError, load_params
from drill_env.yamlio import (
    MAX_INT_DIGITS,
    MAX_YAML_BYTES,
    MAX_YAML_DEPTH,
    MAX_YAML_NODES,
    load_yaml,
    parse_yaml,
)

runner = CliRunner()
ROOT = Path(__file__).resolve().parents[1]


# -- the rules ----------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("text", "value"),
    [
        ("12", 12),
        ("-3", -3),
        ("+7", 7),
        ("0", 0),
        ("0x1F", 31),
        ("0o17", 15),
        ("1.5", 1.5),
        ("5e-4", 5e-4),
        ("-2E+3", -2000.0),
        (".5", 0.5),
        ("1.", 1.0),
        (".inf", math.inf),
        ("-.Inf", -math.inf),
        ("true", True),
        ("False", False),
        ("null", None),
        ("~", None),
        ("", None),
        # YAML 1.1 numbers and booleans that YAML 1.2 reads as strings
        ("017", "017"),
        ("1:30", "1:30"),
        ("1_000", "1_000"),
        ("0b101", "0b101"),
        ("yes", "yes"),
        ("on", "on"),
        ("Off", "Off"),
        ("y", "y"),
        ("2024-01-01", "2024-01-01"),
        ("e5", "e5"),
        ("1e", "1e"),
    ],
)
def test_scalars_follow_yaml_1_2(text, value):
    got = parse_yaml(f"v: {text}")["v"]
    if isinstance(value, float) and math.isinf(value):
        assert got == value
    else:
        assert got == value and type(got) is type(value)


def test_pyyaml_itself_still_reads_yaml_1_1():
    # the rules are the reader's own: PyYAML's SafeLoader is left as it is
    assert yaml.safe_load("v: 017") == {"v": 15}
    assert yaml.safe_load("v: 1:30") == {"v": 90}


def test_a_yaml_1_1_number_where_a_number_is_expected_is_refused_naming_the_field(tmp_path):
    data = load_params("brake").to_dict()
    for text in ("017", "1:30", "1_000"):
        body = yaml.safe_dump(data, sort_keys=False).replace(
            f"lower_static: {data['lower_static']}", f"lower_static: {text}"
        )
        (tmp_path / "rig.yaml").write_text(body)
        with pytest.raises(ParameterError, match=rf"lower_static: expected a number, got '{text}'"):
            load_params(tmp_path / "rig.yaml")


def test_duplicate_keys_are_refused_naming_the_key_and_both_lines():
    with pytest.raises(ValueError, match=r"line 3: duplicate key 'a' \(first on line 1\)"):
        parse_yaml("a: 1\nb: 2\na: 3\n")
    with pytest.raises(ValueError, match=r"line 3: duplicate key 'effects.x' \(first on line 2\)"):
        parse_yaml("effects:\n  x: 1\n  x: 2\n")
    # a merge key ("<<: *anchor") followed by an own key is an override, not a duplicate
    assert parse_yaml("a: &x {p: 1, q: 2}\nb:\n  <<: *x\n  p: 3\n") == {
        "a": {"p": 1, "q": 2},
        "b": {"p": 3, "q": 2},
    }


def test_nesting_is_bounded_without_a_recursion_error():
    ok = "a: " + "[" * (MAX_YAML_DEPTH - 1) + "]" * (MAX_YAML_DEPTH - 1)
    parse_yaml(ok)
    for depth in (MAX_YAML_DEPTH + 1, 900, 20_000):
        with pytest.raises(ValueError, match=rf"nested deeper than {MAX_YAML_DEPTH} levels"):
            parse_yaml("a: " + "[" * depth + "]" * depth)


def test_aliases_count_at_their_expanded_size():
    text = "a: &a [1, 1, 1, 1, 1, 1, 1, 1, 1, 1]\n"
    prev = "a"
    for name in "bcdefgh":
        text += f"{name}: &{name} [" + ", ".join([f"*{prev}"] * 10) + "]\n"
        prev = name
    with pytest.raises(ValueError, match=f"more than {MAX_YAML_NODES} values"):
        parse_yaml(text)


def test_huge_integers_and_float_overflow_are_refused_naming_the_field():
    big = "1" + "0" * 5000
    with pytest.raises(
        ValueError, match=r"line 3: lower\.static: the integer 100000000000\.\.\. \(5001 characters\)"
    ):
        parse_yaml(f"name: x\nlower:\n  static: {big}\n")
    assert parse_yaml("v: " + "9" * MAX_INT_DIGITS)["v"] == int("9" * MAX_INT_DIGITS)
    with pytest.raises(ValueError, match="too large"):
        parse_yaml("v: " + "9" * (MAX_INT_DIGITS + 1))
    with pytest.raises(ValueError, match=r"v\.\[1\]: the number 1e400 overflows a float"):
        parse_yaml("v: [1, 1e400]")
    with pytest.raises(ValueError, match="overflows"):
        parse_yaml("v: -2e308")


def test_size_and_tags_are_bounded(tmp_path):
    (tmp_path / "big.yaml").write_text("a: " + "x" * MAX_YAML_BYTES + "\n")
    with pytest.raises(ValueError, match=f"at most {MAX_YAML_BYTES} bytes"):
        load_yaml(tmp_path / "big.yaml")
    for tag in ("!!timestamp 2020-01-01", "!!binary aGk=", "!!python/object:os.system x", "!!set {a}"):
        with pytest.raises(ValueError, match="not valid YAML"):
            parse_yaml(f"v: {tag}")
    for tag, what in (
        ("!!int abc", "not an integer"),
        ("!!bool maybe", "not true or false"),
        ("!!float x", "not a number"),
    ):
        with pytest.raises(ValueError, match=rf"^<text>: line 1: v: .* is {what}"):
            parse_yaml(f"v: {tag}")


def test_the_committed_configs_read_as_before():
    # every shipped YAML reads the same under the YAML 1.2 rules as PyYAML's 1.1 reading
    # (they hold no number or boolean whose meaning differs)
    files = sorted((ROOT / "configs").rglob("*.yaml")) + sorted((ROOT / "configs").rglob("*.yml"))
    assert len(files) > 10
    for f in files:
        assert load_yaml(f) == yaml.safe_load(f.read_text()), f


# -- every option that reads YAML -------------------------------------------------------------------


def _yaml_options(d: Path, path: str) -> dict[str, list[str]]:
    """The command lines of the options that read a YAML file, each given ``path``."""
    return {
        "simulate --preset": ["simulate", "--preset", path, "--duration", "1"],
        "bifurcation --preset": ["bifurcation", "--preset", path, "--out", str(d / "bif"), "--no-check"],
        "rig-comparison --params": ["rig-comparison", "--params", path],
        # --out a file (see _bench_file)
        "benchmark --plant": ["benchmark", "--plant", path, "--out", str(d / "bench"), "--quick"],
        "benchmark --gains": ["benchmark", "--gains", path, "--out", str(d / "bench"), "--quick"],
        "train --config": ["train", "--algo", "ppo", "--config", path, "--out", str(d / "train")],
        "train --params": [
            "train",
            "--algo",
            "ppo",
            "--config",
            "ppo",
            "--params",
            path,
            "--out",
            str(d / "t"),
        ],
        "tune --params": ["tune", "--params", path, "--out", str(d / "gains.yaml")],
        "benchmark --design-params": [
            "benchmark",
            "--design-params",
            path,
            "--preset",
            "brake",
            "--out",
            str(d / "bench"),
            "--quick",
        ],
        "synth --plant": ["synth", "--plant", path, "--out", str(d / "s"), "--answer", str(d / "a.json")],
        "synth --params": [
            "synth",
            "--effect",
            "none",
            "--params",
            path,
            "--out",
            str(d / "s"),
            "--answer",
            str(d / "a.json"),
        ],
        # the dataset is read after the nominal model: a missing one is never reached
        "discrepancy --params": [
            "discrepancy",
            str(d / "no-data"),
            "--params",
            path,
            "--out",
            str(d / "disc"),
        ],
        "sim-to-real --truth": ["sim-to-real", "--truth", path, "--out", str(d / "s2r"), "--quick"],
    }


def _bench_file(d: Path) -> None:
    """A file where the benchmark's --out goes: refused after its YAML is read, so that a valid
    file never starts a benchmark."""
    (d / "bench").write_text("not a folder\n")


BAD_FILES = {
    "deep": ("a: " + "[" * 900 + "]" * 900 + "\n", ["nested deeper than"]),
    "duplicate": (
        "name: x\nmotor_constant: 3.5\nmotor_constant: 4\n",
        ["duplicate key 'motor_constant'", "line 3"],
    ),
    "huge-int": ("motor_constant: 1" + "0" * 5000 + "\n", ["motor_constant", "too large"]),
    "overflow": ("motor_constant: 1e999\n", ["motor_constant", "overflows"]),
    "nul": ("name: x\nmotor_constant: 3.5\x00\n", ["line 2, column 20", "U+0000 (NUL)"]),
    "bel": ("name: x\x07\n", ["line 1, column 8", "U+0007 (BEL)"]),
    "esc": ("name: x\nlower_static: 1\ndescription: \x1b[31mred\n", ["line 3, column 14", "U+001B (ESC)"]),
    "cr-only": ("name: x\rmotor_constant: 3.5\r", ["line 1, column 8", "CR not followed by LF"]),
    "python-tag": ("name: !!python/object/apply:os.system ['true']\n", ["not valid YAML", "line 1"]),
    "laughs": (
        "a: &a [x, x, x, x, x, x, x, x, x, x]\n"
        + "".join(
            f"{c}: &{c} [{', '.join(['*' + p] * 10)}]\n" for p, c in zip("abcdefgh", "bcdefghi", strict=True)
        )
        + "name: *i\n",
        ["more than", "expanded size"],
    ),
}


def _one_error_line(res) -> str:
    assert res.exit_code == 2, (res.exit_code, res.output)
    assert "Traceback" not in res.output
    assert res.exception is None or isinstance(res.exception, SystemExit), res.exception
    lines = [ln for ln in res.output.splitlines() if ln.strip()]
    errors = [ln for ln in lines if ln.startswith("error:")]
    assert len(errors) == 1, res.output
    return errors[0]


@pytest.mark.parametrize("kind", sorted(BAD_FILES))
@pytest.mark.parametrize("option", sorted(_yaml_options(Path("."), "x")))
def test_every_yaml_option_refuses_a_bad_file_in_one_line(tmp_path, option, kind):
    text, words = BAD_FILES[kind]
    _bench_file(tmp_path)
    path = tmp_path / f"{kind}.yaml"
    path.write_bytes(text.encode())  # as given: no newline translation
    line = _one_error_line(runner.invoke(app, _yaml_options(tmp_path, str(path))[option]))
    assert f"{kind}.yaml" in line
    for w in words:
        assert w in line, line
    assert not (tmp_path / "bif").exists()


# -- the fuzzer --------------------------------------------------------------------------------------

_scalars = st.one_of(
    st.sampled_from(
        [
            "017",
            "1:30",
            "1_000",
            "0x1F",
            "0o17",
            "yes",
            "no",
            "on",
            "~",
            "null",
            ".inf",
            "-.inf",
            ".nan",
            "1e400",
            "-1e999",
            "1" + "0" * 5000,
            "-" + "9" * 40,
            "5e-4",
            "1e-330",
            "3.5",
            "2024-01-01",
            "'quoted'",
            "!!binary aGk=",
            "!!int abc",
            "!!int 0b101",
            "!!bool maybe",
            "!!float x",
            "!!str [1]",
            "!!set {a}",
            "*nowhere",
            "&a 1",
            "<<",
            "true",
        ]
    ),
    st.integers(-(10**30), 10**30).map(str),
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.text(alphabet=string.ascii_letters + string.digits + ".:-_ ", max_size=12),
)
_keys = st.one_of(
    # no "algo": a training config of one known key could be complete
    st.sampled_from(["motor_constant", "lower_static", "effects", "brake", "name", "sensors", "env_id"]),
    st.text(alphabet=string.ascii_lowercase + "_", min_size=1, max_size=8),
)


@st.composite
def _yaml_texts(draw) -> str:
    """YAML-like text: nested block mappings and flow lists of awkward scalars, sometimes with a
    repeated key, deep nesting or a broken line."""
    lines: list[str] = []
    for _ in range(draw(st.integers(1, 6))):
        key = draw(_keys)
        indent = "  " * draw(st.integers(0, 2))
        kind = draw(st.integers(0, 4))
        if kind == 0:
            lines.append(f"{indent}{key}: {draw(_scalars)}")
        elif kind == 1:
            items = draw(st.lists(_scalars, max_size=4))
            lines.append(f"{indent}{key}: [{', '.join(items)}]")
        elif kind == 2:
            depth = draw(st.sampled_from([1, 5, MAX_YAML_DEPTH, MAX_YAML_DEPTH + 5, 500]))
            lines.append(f"{indent}{key}: " + "[" * depth + draw(_scalars) + "]" * depth)
        elif kind == 3:
            lines.append(f"{indent}{key}:")
            lines.append(f"{indent}  {draw(_keys)}: {draw(_scalars)}")
        else:
            lines.append(f"{indent}{key}: {draw(_scalars)}")
            lines.append(f"{indent}{key}: {draw(_scalars)}")  # a duplicate
    return "\n".join(lines) + "\n"


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(text=_yaml_texts())
def test_fuzz_the_reader_returns_data_or_one_value_error(text):
    try:
        data = parse_yaml(text, source="f.yaml")
    except ValueError as exc:
        msg = str(exc)
        assert msg.startswith("f.yaml: ") and "\n" not in msg
        return

    # what it returns is plain data within the bounds
    def walk(x, depth=0):
        assert depth <= MAX_YAML_DEPTH
        if isinstance(x, dict):
            for k, v in x.items():
                walk(k, depth + 1)
                walk(v, depth + 1)
        elif isinstance(x, list):
            for v in x:
                walk(v, depth + 1)
        else:
            assert x is None or isinstance(x, (bool, int, float, str))
            if isinstance(x, int) and not isinstance(x, bool):
                assert abs(x) < 10**MAX_INT_DIGITS

    walk(data)


@settings(
    max_examples=25,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
)
@given(text=_yaml_texts(), option=st.sampled_from(sorted(_yaml_options(Path("."), "x"))))
def test_fuzz_every_yaml_option_ends_in_one_error_line(tmp_path, text, option):
    """Random YAML in every option that reads YAML: exit 2 and one ``error:`` line naming the
    file, before any output is made (random text is never a complete valid file)."""
    _bench_file(tmp_path)
    path = tmp_path / "fuzz.yaml"
    path.write_text(text)
    res = runner.invoke(app, _yaml_options(tmp_path, str(path))[option])
    line = _one_error_line(res)
    assert "fuzz.yaml" in line or "--" in line, line


def test_api_rig_file_errors_are_parameter_errors(tmp_path):
    (tmp_path / "rig.yaml").write_text("a: " + "[" * 900 + "]" * 900 + "\n")
    with pytest.raises(ParameterError, match="nested deeper"):
        drill_env.simulate(str(tmp_path / "rig.yaml"), 1.0, 1.0)
