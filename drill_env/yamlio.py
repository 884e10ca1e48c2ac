"""The one YAML reader of drill-env: every rig file, training config, gains file and policy
config goes through :func:`load_yaml`.

What it accepts is YAML 1.2's core schema, bounded:

* numbers follow YAML 1.2: ``12``, ``-3``, ``0x1F``, ``0o17``, ``1.5``, ``5e-4``, ``.inf``;
  a number with a leading zero (``017``), a sexagesimal (``1:30``), underscores (``1_000``)
  or any other form YAML 1.1 read as a number stays a string, and a string where a number
  is expected is refused by whoever reads the field;
* booleans are ``true`` and ``false`` only (``yes``, ``on``, ``y`` are strings); null is
  ``null``, ``~`` or nothing; dates stay strings;
* a key given twice in one mapping is refused, naming the key and both lines;
* at most :data:`MAX_YAML_BYTES` bytes, :data:`MAX_YAML_DEPTH` levels of nesting and
  :data:`MAX_YAML_NODES` values (aliases counted at their expanded size);
* an integer of more than :data:`MAX_INT_DIGITS` digits, or a float literal beyond the
  float range (``1e400``), is refused naming the field.

Every failure is one exception of the caller's type (``error``) with a one-line message
naming the file (and the line where there is one).
"""

from __future__ import annotations

import re
import stat
from pathlib import Path
from typing import Any

import yaml
from yaml.constructor import ConstructorError
from yaml.nodes import MappingNode, ScalarNode, SequenceNode

__all__ = [
    "MAX_YAML_BYTES",
    "MAX_YAML_DEPTH",
    "MAX_YAML_NODES",
    "MAX_INT_DIGITS",
    "load_yaml",
    "parse_yaml",
]

MAX_YAML_BYTES = 1 << 20  # a configuration file is small; anything larger is not one
MAX_YAML_DEPTH = 32  # levels of nesting (a rig file uses 2, a training config 4)
MAX_YAML_NODES = 100_000  # values in one file, aliases counted at their expanded size
MAX_INT_DIGITS = 18  # |n| < 10**18 (an int64 holds it); longer integers are refused

# YAML 1.2 core schema (https://yaml.org/spec/1.2.2/#1032-tag-resolution), except that a
# decimal integer has no leading zero, so "017" stays a string rather than 17 or (1.1) 15.
_INT = re.compile(r"^(?:[-+]?(?:0|[1-9][0-9]*)|0o[0-7]+|0x[0-9a-fA-F]+)$")
_FLOAT = re.compile(
    r"^(?:[-+]?(?:(?:0|[1-9][0-9]*)(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][-+]?[0-9]+)?"
    r"|[-+]?\.(?:inf|Inf|INF)|\.(?:nan|NaN|NAN))$"
)
_BOOL = re.compile(r"^(?:true|True|TRUE|false|False|FALSE)$")
_NULL = re.compile(r"^(?:~|null|Null|NULL|)$")


# Characters YAML does not allow in a stream (C0 controls but tab, LF and CR; DEL; C1
# controls but NEL; surrogates; U+FFFE/U+FFFF), and a CR that does not end a CR LF pair: a
# file of CR-only line endings reads as one line in some readers and many in others.
_CONTROL = re.compile("[\x00-\x08\x0b\x0c\x0e-\x1f\x7f-\x84\x86-\x9f\ud800-\udfff\ufffe\uffff]|\r(?!\n)")
_CONTROL_NAMES = {
    "\x00": "NUL",
    "\x07": "BEL",
    "\x08": "BS",
    "\x1b": "ESC",
    "\x7f": "DEL",
    "\r": "a CR not followed by LF",
}


class _Bounded(ValueError):
    """A bound of this reader exceeded (the message names it)."""


def _where(node: Any) -> str:
    mark = getattr(node, "start_mark", None)
    return f"line {mark.line + 1}" if mark is not None else "?"


class _Loader(yaml.SafeLoader):
    """PyYAML's SafeLoader with YAML 1.2 core resolvers, duplicate keys refused and bounds."""

    def __init__(self, stream: str) -> None:
        super().__init__(stream)
        self._depth = 0
        self._nodes = 0
        self._sizes: dict[int, int] = {}  # id(node) -> values under it (for aliases)
        self._path: list[str] = []

    # -- composing: depth and size -------------------------------------------------------------
    def compose_node(self, parent: Any, index: Any) -> Any:  # noqa: ANN401 (PyYAML's signature)
        if self.check_event(yaml.AliasEvent):
            event = self.peek_event()
            node = super().compose_node(parent, index)
            self._count(self._sizes.get(id(node), 1), event)
            return node
        self._depth += 1
        if self._depth > MAX_YAML_DEPTH:
            event = self.peek_event()
            raise _Bounded(
                f"line {event.start_mark.line + 1}: nested deeper than {MAX_YAML_DEPTH} levels; "
                f"allowed: at most {MAX_YAML_DEPTH}"
            )
        before = self._nodes
        try:
            self._count(1, self.peek_event())
            node = super().compose_node(parent, index)
        finally:
            self._depth -= 1
        self._sizes[id(node)] = self._nodes - before
        return node

    def _count(self, n: int, event: Any) -> None:
        self._nodes += n
        if self._nodes > MAX_YAML_NODES:
            raise _Bounded(
                f"line {event.start_mark.line + 1}: more than {MAX_YAML_NODES} values (aliases "
                f"counted at their expanded size); allowed: at most {MAX_YAML_NODES}"
            )

    # -- constructing: field names, duplicate keys, number bounds -------------------------------
    def _field(self) -> str:
        return ".".join(self._path) if self._path else "(top level)"

    def construct_mapping(self, node: Any, deep: bool = False) -> dict[Any, Any]:  # noqa: ARG002
        if not isinstance(node, MappingNode):
            raise ConstructorError(None, None, f"expected a mapping, found {node.id}", node.start_mark)
        explicit = sum(1 for k, _ in node.value if k.tag != "tag:yaml.org,2002:merge")
        self.flatten_mapping(node)  # merge keys ("<<: *anchor") are put first, then the file's own
        merged = len(node.value) - explicit
        mapping: dict[Any, Any] = {}
        first: dict[Any, Any] = {}
        for i, (key_node, value_node) in enumerate(node.value):
            key = self.construct_object(key_node, deep=True)
            try:
                hash(key)
            except TypeError:
                raise ConstructorError(
                    None, None, f"a mapping key must be a scalar, found {key_node.id}", key_node.start_mark
                ) from None
            if i >= merged:  # a key of the file itself (it may override a merged one)
                if key in first:
                    raise _Bounded(
                        f"{_where(key_node)}: duplicate key {'.'.join([*self._path, str(key)])!r} "
                        f"(first on {_where(first[key])}); each key may appear once in a mapping"
                    )
                first[key] = key_node
            self._path.append(str(key))
            try:
                mapping[key] = self.construct_object(value_node, deep=True)
            finally:
                self._path.pop()
        return mapping

    def construct_sequence(self, node: Any, deep: bool = False) -> list[Any]:  # noqa: ARG002
        if not isinstance(node, SequenceNode):
            raise ConstructorError(None, None, f"expected a sequence, found {node.id}", node.start_mark)
        out = []
        for i, child in enumerate(node.value):
            self._path.append(f"[{i}]")
            try:
                out.append(self.construct_object(child, deep=True))
            finally:
                self._path.pop()
        return out

    def construct_yaml_map(self, node: Any) -> Any:  # noqa: ANN401
        yield self.construct_mapping(node)

    def construct_yaml_seq(self, node: Any) -> Any:  # noqa: ANN401
        yield self.construct_sequence(node)

    def construct_yaml_int(self, node: ScalarNode) -> int:
        text = str(self.construct_scalar(node))
        digits = text.lstrip("+-")
        if digits.startswith(("0x", "0o")) and len(digits) > 2:
            try:
                value = int(digits[2:], 16 if digits[1] == "x" else 8)
            except ValueError:
                raise _Bounded(f"{_where(node)}: {self._field()}: {text[:40]!r} is not an integer") from None
            value = -value if text.startswith("-") else value
            if abs(value) >= 10**MAX_INT_DIGITS:
                raise self._too_large(node, text)
            return value
        if len(digits) > MAX_INT_DIGITS:
            raise self._too_large(node, text)
        try:
            return int(text)
        except ValueError:  # an explicit "!!int" on text that is none
            raise _Bounded(f"{_where(node)}: {self._field()}: {text[:40]!r} is not an integer") from None

    def _too_large(self, node: Any, text: str) -> _Bounded:
        shown = text if len(text) <= 24 else f"{text[:12]}... ({len(text)} characters)"
        return _Bounded(
            f"{_where(node)}: {self._field()}: the integer {shown} is too large; allowed: |n| < 1e{MAX_INT_DIGITS}"
        )

    def construct_yaml_bool(self, node: ScalarNode) -> bool:
        text = str(self.construct_scalar(node))
        if not _BOOL.match(text):  # an explicit "!!bool" on text that is neither
            raise _Bounded(f"{_where(node)}: {self._field()}: {text[:40]!r} is not true or false")
        return text.lower() == "true"

    def construct_yaml_float(self, node: ScalarNode) -> float:
        text = str(self.construct_scalar(node))
        low = text.lower().lstrip("+-")
        if low in (".inf", ".nan"):
            return float(low[1:]) * (-1.0 if text.startswith("-") else 1.0)
        try:
            value = float(text)
        except ValueError:  # an explicit "!!float" on text that is none
            raise _Bounded(f"{_where(node)}: {self._field()}: {text[:40]!r} is not a number") from None
        if value in (float("inf"), float("-inf")):
            shown = text if len(text) <= 24 else f"{text[:12]}... ({len(text)} characters)"
            raise _Bounded(
                f"{_where(node)}: {self._field()}: the number {shown} overflows a float; "
                "allowed: |x| <= 1.8e308"
            )
        return value


def _resolvers() -> dict[Any, list[tuple[str, Any]]]:
    table: dict[Any, list[tuple[str, Any]]] = {}

    def add(tag: str, regexp: re.Pattern[str], first: str | None) -> None:
        for ch in first if first is not None else [None]:
            table.setdefault(ch, []).append((tag, regexp))

    add("tag:yaml.org,2002:bool", _BOOL, "tTfF")
    add("tag:yaml.org,2002:int", _INT, "-+0123456789")
    add("tag:yaml.org,2002:float", _FLOAT, "-+0123456789.")
    add("tag:yaml.org,2002:null", _NULL, "~nN")
    table.setdefault("", []).append(("tag:yaml.org,2002:null", _NULL))
    add("tag:yaml.org,2002:merge", re.compile(r"^(?:<<)$"), "<")
    return table


_Loader.yaml_implicit_resolvers = _resolvers()
_Loader.add_constructor("tag:yaml.org,2002:map", _Loader.construct_yaml_map)
_Loader.add_constructor("tag:yaml.org,2002:seq", _Loader.construct_yaml_seq)
_Loader.add_constructor("tag:yaml.org,2002:int", _Loader.construct_yaml_int)
_Loader.add_constructor("tag:yaml.org,2002:float", _Loader.construct_yaml_float)
_Loader.add_constructor("tag:yaml.org,2002:bool", _Loader.construct_yaml_bool)
# Explicit tags that YAML 1.2's core schema does not have are refused (a "!!timestamp",
# "!!binary", "!!set" or "!!omap" value is not a configuration value).
for _tag in ("timestamp", "binary", "set", "omap", "pairs"):
    _Loader.yaml_constructors.pop(f"tag:yaml.org,2002:{_tag}", None)


def parse_yaml(
    text: str, *, source: str = "<text>", what: str = "YAML file", error: type[Exception] = ValueError
) -> Any:  # noqa: ANN401
    """Parse YAML text by the rules of this module; failures are ``error`` naming ``source``."""
    if len(text.encode("utf-8", "surrogatepass")) > MAX_YAML_BYTES:
        raise error(
            f"{source}: larger than {MAX_YAML_BYTES} bytes; a {what} is at most {MAX_YAML_BYTES} bytes"
        )
    bad = _CONTROL.search(text)
    if bad is not None:
        line = text.count("\n", 0, bad.start()) + 1
        col = bad.start() - (text.rfind("\n", 0, bad.start()) + 1) + 1
        raise error(
            f"{source}: line {line}, column {col}: control character U+{ord(bad.group()):04X} "
            f"({_CONTROL_NAMES.get(bad.group(), 'not printable')}); allowed: printable text, tab "
            "and line feed (LF or CR LF line endings)"
        )
    loader = _Loader(text)
    try:
        return loader.get_single_data()
    except _Bounded as exc:
        raise error(f"{source}: {exc}") from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" (line {mark.line + 1}, column {mark.column + 1})" if mark is not None else ""
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise error(f"{source}: not valid YAML{where}: {problem}") from None
    except (KeyError, TypeError, ValueError, IndexError, AttributeError) as exc:  # a last guard
        raise error(f"{source}: not valid YAML: {type(exc).__name__}: {exc}"[:300]) from None
    except RecursionError:  # not reached within the depth bound; kept as a last guard
        raise error(f"{source}: nested too deeply; allowed: at most {MAX_YAML_DEPTH} levels") from None
    finally:
        loader.dispose()


def load_yaml(path: str | Path, *, what: str = "YAML file", error: type[Exception] = ValueError) -> Any:  # noqa: ANN401
    """Read and parse a small YAML file; every failure is ``error`` with a one-line message
    naming the file.

    A file that is missing, not a regular file (a folder, a FIFO), larger than
    :data:`MAX_YAML_BYTES`, not UTF-8 text or not valid YAML (by the rules of this module)
    is refused, with the line of the problem where there is one.
    """
    path = Path(path)
    try:
        st = path.stat()
    except OSError as exc:
        raise error(f"{path}: cannot read the {what}: {exc.strerror or exc}") from None
    if not stat.S_ISREG(st.st_mode):
        raise error(f"{path}: not a regular file; expected a {what}")
    if st.st_size > MAX_YAML_BYTES:
        raise error(f"{path}: {st.st_size} bytes; a {what} is at most {MAX_YAML_BYTES} bytes")
    try:
        with open(path, "rb") as f:
            raw = f.read(MAX_YAML_BYTES + 1)  # the file may have grown since stat
    except OSError as exc:
        raise error(f"{path}: cannot read the {what}: {exc.strerror or exc}") from None
    if len(raw) > MAX_YAML_BYTES:
        raise error(f"{path}: more than {MAX_YAML_BYTES} bytes; a {what} is at most {MAX_YAML_BYTES} bytes")
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise error(
            f"{path}: not UTF-8 text (byte {exc.start} is 0x{raw[exc.start]:02x}); expected a {what}"
        ) from None
    return parse_yaml(text, source=str(path), what=what, error=error)
