"""YAML as YAML 1.2's core schema reads it, on PyYAML (libyaml's parser where installed).

PyYAML implements YAML 1.1, which reads ``010`` as 8, ``1:30`` as 90, ``NO`` and ``off`` as false,
keeps the last of two equal keys and expands aliases without limit. Here the same parser's nodes
are resolved by the core schema's four implicit types (YAML 1.2.2, §10.3.2) and everything else is
text; mapping keys are always the text as written (a goal named ``NO``, ``1`` or ``1e3`` keeps its
name); a number keeps its written text (:func:`written`) for fields that are names; a key given
twice is an error naming both lines; a document whose aliases expand beyond :data:`MAX_CHARS`
(the billion laughs) or that nests deeper than :data:`MAX_DEPTH` is refused before it is built.
"""

from __future__ import annotations

import re

import yaml
from yaml.nodes import MappingNode, ScalarNode, SequenceNode

#: A scenario is a few kilobytes; a thousand objects take about 60 kB. The cap bounds the text
#: given and the text its aliases expand to (each alias counts as a copy of what it points to).
MAX_CHARS = 1_000_000
MAX_DEPTH = 20  #: a scenario nests 4 levels (events[0].box[0]); the cap keeps walks shallow


class YAMLInputError(ValueError):
    """Text that is not a YAML document this module accepts; the message names where."""


_INT = re.compile(r"[-+]?[0-9]+|0o[0-7]+|0x[0-9a-fA-F]+")
_FLOAT = re.compile(r"[-+]?(?:\.[0-9]+|[0-9]+(?:\.[0-9]*)?)(?:[eE][-+]?[0-9]+)?"
                    r"|[-+]?\.(?:inf|Inf|INF)|\.nan|\.NaN|\.NAN")
_BOOL = {"true": True, "True": True, "TRUE": True, "false": False, "False": False, "FALSE": False}
_NULL = ("", "~", "null", "Null", "NULL")


class _Resolver(yaml.resolver.BaseResolver):
    """The core schema's implicit tags (a plain scalar matching none of them is text)."""


for _tag, _pattern, _first in (
    ("null", "|".join(map(re.escape, _NULL)), ["", "~", "n", "N"]),
    ("bool", "|".join(_BOOL), list("tTfF")),
    ("int", _INT.pattern, list("-+0123456789")),
    ("float", _FLOAT.pattern, list("-+0123456789.")),
):
    _Resolver.add_implicit_resolver(f"tag:yaml.org,2002:{_tag}",
                                    re.compile(f"(?:{_pattern})\\Z"), _first)


class _Int(int):
    """An integer that remembers how it was written (``010``, ``0x1F``)."""


class _Float(float):
    """A number that remembers how it was written (``1e3``, ``.5``)."""


def written(value):
    """The text ``value`` was written as, if it is a number read here; else ``value``."""
    return getattr(value, "text", value)


class _Constructor(yaml.constructor.SafeConstructor):
    """Values by the core schema; mapping keys as text; no YAML 1.1 merge keys (``<<``).
    ``where`` names the text in errors."""

    def construct_yaml_null(self, node):
        self.construct_scalar(node)

    def construct_yaml_bool(self, node):
        text = self.construct_scalar(node)
        if text not in _BOOL:
            raise self._error(node, f"{text!r} is not true or false")
        return _BOOL[text]

    def construct_yaml_int(self, node):
        text = self.construct_scalar(node)
        if not _INT.fullmatch(text):
            raise self._error(node, f"{text!r} is not an integer")
        base = {"0o": 8, "0x": 16}.get(text[:2], 10)
        try:
            value = _Int(text[2:] if base != 10 else text, base)
        except ValueError as err:  # more digits than Python converts (sys.int_info)
            raise self._error(node, f"an integer of {len(text):,} digits") from err
        value.text = text
        return value

    def construct_yaml_float(self, node):
        text = self.construct_scalar(node)
        if not _FLOAT.fullmatch(text):
            raise self._error(node, f"{text!r} is not a number")
        value = _Float(text.lower().replace(".inf", "inf").replace(".nan", "nan"))
        value.text = text
        return value

    def construct_mapping(self, node, deep=False):
        if not isinstance(node, MappingNode):
            raise self._error(node, f"expected a mapping, found a {node.id}")
        mapping, lines = {}, {}
        for key_node, value_node in node.value:
            if not isinstance(key_node, ScalarNode):
                raise self._error(key_node, f"a key must be text, not a {key_node.id}")
            key = key_node.value
            if key in lines:
                raise self._error(key_node, f"duplicate key {key!r} (first at "
                                            f"{self.where}:{lines[key]})")
            lines[key] = _line(key_node)
            mapping[key] = self.construct_object(value_node, deep=deep)
        return mapping

    def _error(self, node, problem: str) -> YAMLInputError:
        return YAMLInputError(f"{self.where}:{_line(node)}: {problem}")


for _tag in ("null", "bool", "int", "float"):
    _Constructor.add_constructor(f"tag:yaml.org,2002:{_tag}",
                                 getattr(_Constructor, f"construct_yaml_{_tag}"))

if yaml.__with_libyaml__:  # libyaml's parser: a large scene loads several times faster
    class _Parser(yaml.cyaml.CParser):
        pass
else:
    class _Parser(yaml.reader.Reader, yaml.scanner.Scanner, yaml.parser.Parser,
                  yaml.composer.Composer):
        def __init__(self, stream: str) -> None:
            yaml.reader.Reader.__init__(self, stream)
            yaml.scanner.Scanner.__init__(self)
            yaml.parser.Parser.__init__(self)
            yaml.composer.Composer.__init__(self)


class _Loader(_Parser, _Constructor, _Resolver):
    def __init__(self, stream: str, where: str) -> None:
        self.where = where
        _Parser.__init__(self, stream)
        _Constructor.__init__(self)
        _Resolver.__init__(self)


def _line(node) -> int:
    return node.start_mark.line + 1


def load(text: str, where: str):
    """The one YAML document in ``text`` (None if empty); :class:`YAMLInputError` naming
    ``where`` (a path, or ``override``) and the line if it is not one this module accepts."""
    if len(text) > MAX_CHARS:
        raise YAMLInputError(f"{where}: longer than {MAX_CHARS:,} characters")
    try:
        loader = _Loader(text, where)
        try:
            node = loader.get_single_node()
            if node is None:
                return None
            _check_size(node, where)
            return loader.construct_document(node)
        finally:
            loader.dispose()
    except yaml.MarkedYAMLError as err:  # one line: where, the line, what libyaml says
        mark = err.problem_mark or err.context_mark
        at = f"{where}:{mark.line + 1}" if mark else where
        if "nesting depth" in str(err.problem):
            raise YAMLInputError(f"{at}: nested too deeply") from err
        says = ", ".join(filter(None, (err.context, err.problem)))
        if mark and "\t" in (text.splitlines()[mark.line:] or [""])[0][:mark.column + 1]:
            says += " (a tab: YAML indents with spaces)"
        raise YAMLInputError(f"{at}: not valid YAML: {says}") from err
    except (yaml.YAMLError, RecursionError) as err:
        raise YAMLInputError(f"{where}: not valid YAML: {' '.join(str(err).split())}") from err


def _check_size(root, where: str) -> None:
    """Refuse a document nested deeper than MAX_DEPTH, with an alias to a node that contains it
    (a cycle) or longer than MAX_CHARS with its aliases expanded, before anything is built: a
    shared node is measured once, so a billion laughs is refused after a few hundred nodes."""
    size: dict[int, int] = {}
    open_: set[int] = set()

    def measure(node, depth: int) -> int:
        if id(node) in size:
            return size[id(node)]
        if id(node) in open_:
            raise YAMLInputError(f"{where}:{_line(node)}: an alias inside the node it names")
        if depth > MAX_DEPTH:
            raise YAMLInputError(f"{where}:{_line(node)}: nested too deeply (more than "
                                 f"{MAX_DEPTH} levels)")
        open_.add(id(node))
        if isinstance(node, ScalarNode):
            n = 1 + len(node.value)
        elif isinstance(node, SequenceNode):
            n = 1 + sum(measure(item, depth + 1) for item in node.value)
        else:
            n = 1 + sum(measure(k, depth + 1) + measure(v, depth + 1) for k, v in node.value)
        open_.discard(id(node))
        if n > MAX_CHARS:
            raise YAMLInputError(f"{where}:{_line(node)}: more than {MAX_CHARS:,} characters "
                                 "with its aliases (*name) expanded")
        size[id(node)] = n
        return n

    measure(root, 0)
