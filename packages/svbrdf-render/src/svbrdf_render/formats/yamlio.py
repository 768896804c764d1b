"""YAML as people write it: ``3e-4`` is a number.

PyYAML follows YAML 1.1, where a float needs a dot and a signed exponent: ``3e-4``,
``1e5`` and ``1.5e3`` come back as strings, so a file that says ``lr: 3e-4`` is refused
while ``--set optim.lr=3e-4`` is not. :func:`safe_load` is ``yaml.safe_load`` with YAML
1.2's float syntax added; everything else (ints, bools, nulls, dates) reads as before.
Scene files (svbrdf-render) and recipe files and ``--set`` values (svbrdf-train) are all
read with it.

It also refuses, with a one-line ``yaml.YAMLError`` naming the key or the line, what
``yaml.safe_load`` accepts silently or pays for later:

- a key given twice in one mapping (``yaml.safe_load`` keeps the last one without a word);
  merge keys (``<<: *base``) may still be overridden, that is what they are for;
- nesting deeper than :data:`MAX_DEPTH` levels (PyYAML composes recursively: a few thousand
  levels end in a ``RecursionError``);
- aliases that expand the document beyond :data:`MAX_VALUES` values, or nest it beyond
  :data:`MAX_DEPTH` levels through aliases, and an alias inside the node it names (an
  "alias bomb": a few lines that every reader of the result then walks as billions of
  values). These are checked on the composed node graph, before anything is constructed.
"""

from __future__ import annotations

import re
from typing import Any

from .._optional import require

__all__ = ["safe_load", "loader", "MAX_DEPTH", "MAX_VALUES"]

#: YAML 1.2 floats that 1.1 reads as strings: no dot (``3e-4``, ``1e5``), an unsigned
#: exponent (``1.5e3``), a signed leading dot (``-.5``). Tried after YAML 1.1's own
#: resolvers, so ``4`` stays an int and ``2024-01-01`` a date.
_FLOAT = re.compile(
    r"""^[-+]?(?:(?:\.[0-9_]+|[0-9][0-9_]*\.[0-9_]*)(?:[eE][-+]?[0-9]+)?|[0-9][0-9_]*[eE][-+]?[0-9]+)$""",
)

#: Deepest nesting of mappings and sequences a document may have (scenes and recipes use ~5).
MAX_DEPTH = 100
#: Most values (scalars, mappings, sequences) a document with aliases may expand to.
MAX_VALUES = 100_000

_LOADER = None


def _refuse(yaml, problem: str):
    """A one-line YAML error (no source excerpt): callers prefix the file's name."""
    return yaml.MarkedYAMLError(problem=problem)


def _check_expansion(yaml, root) -> None:
    """Refuse a node graph whose aliases expand it beyond MAX_VALUES values or MAX_DEPTH levels,
    or that holds a node inside itself; each node is sized once, without recursion."""
    sizes: dict[int, tuple[int, int]] = {}  # id(node) -> (values, depth) once expanded
    open_nodes: set[int] = set()  # the node being sized and its ancestors
    stack = [(root, False)]
    while stack:
        node, closing = stack.pop()
        if isinstance(node, yaml.MappingNode):
            children = [c for pair in node.value for c in pair]  # keys and values
        else:
            children = node.value if isinstance(node, yaml.SequenceNode) else []
        if closing:
            open_nodes.discard(id(node))
            values = 1 + sum(sizes[id(c)][0] for c in children)
            depth = 1 + max((sizes[id(c)][1] for c in children), default=0)
            if values > MAX_VALUES:
                raise _refuse(yaml, f"aliases expand the document to more than {MAX_VALUES} values "
                              f"(line {node.start_mark.line + 1}); write the values out instead")
            if depth > MAX_DEPTH:
                raise _refuse(yaml, f"aliases nest the document deeper than {MAX_DEPTH} levels "
                              f"(line {node.start_mark.line + 1})")
            sizes[id(node)] = (values, depth)
            continue
        if id(node) in sizes:
            continue
        open_nodes.add(id(node))
        stack.append((node, True))
        for child in children:
            if id(child) in open_nodes:
                raise _refuse(yaml, f"an alias at line {child.start_mark.line + 1} names a node that "
                              "holds it (a document cannot contain itself)")
            if id(child) not in sizes:
                stack.append((child, False))


def loader():
    """The ``yaml.SafeLoader`` subclass that :func:`safe_load` uses."""
    global _LOADER
    if _LOADER is None:
        yaml = require("yaml", "PyYAML", "reading YAML")

        class Loader(yaml.SafeLoader):
            """SafeLoader that also reads ``3e-4`` and ``1e5`` as floats (YAML 1.2), and refuses
            duplicate keys, deep nesting and alias bombs (see the module's docstring)."""

            _depth = 0
            _aliases = 0

            def compose_document(self):
                node = super().compose_document()
                if self._aliases and node is not None:
                    _check_expansion(yaml, node)
                return node

            def compose_node(self, parent, index):
                if self.check_event(yaml.AliasEvent):
                    self._aliases += 1
                    return super().compose_node(parent, index)
                self._depth += 1
                try:
                    if self._depth > MAX_DEPTH:
                        line = self.peek_event().start_mark.line + 1
                        raise _refuse(yaml, f"nested deeper than {MAX_DEPTH} levels (line {line})")
                    return super().compose_node(parent, index)
                finally:
                    self._depth -= 1

            def compose_mapping_node(self, anchor):
                node = super().compose_mapping_node(anchor)
                first: dict[tuple[str, str], int] = {}
                for key, _ in node.value:
                    if not isinstance(key, yaml.ScalarNode) or key.tag == "tag:yaml.org,2002:merge":
                        continue
                    line = key.start_mark.line + 1
                    if (key.tag, key.value) in first:
                        where = f"lines {first[key.tag, key.value]} and {line}"
                        raise _refuse(yaml, f"duplicate key {key.value!r} ({where}); keep one of them")
                    first[key.tag, key.value] = line
                return node

        Loader.add_implicit_resolver("tag:yaml.org,2002:float", _FLOAT, list("-+0123456789."))
        _LOADER = Loader
    return _LOADER


def safe_load(text: str) -> Any:
    """``yaml.safe_load(text)``, with ``3e-4`` read as the number; raises ``yaml.YAMLError``."""
    yaml = require("yaml", "PyYAML", "reading YAML")
    return yaml.load(text, Loader=loader())  # noqa: S506 - a SafeLoader subclass
