"""YAML loading that remembers where every key came from, so errors name file, line and key."""
from __future__ import annotations

import os
import stat
from pathlib import Path
from typing import Any

import numpy as np
import yaml

MAX_FILE_BYTES = 1 << 20  # no graph, layout or device file is near this; a bigger one is refused unread
MAX_DEPTH = 64  # nesting of mappings/lists
MAX_NODES = 200_000  # values once aliases are expanded (an alias bomb expands to billions)


class GraphError(ValueError):
    """A problem in a graph file: ``file:line: key: message`` (one line, no traceback)."""

    def __init__(self, file: str | Path, line: int | None, key: str, message: str) -> None:
        self.file = str(file)
        self.line = line
        self.key = key
        self.message = message
        super().__init__(str(self))

    def __str__(self) -> str:
        where = f"{self.file}:{self.line}" if self.line else self.file
        return f"{where}: {self.key}: {self.message}" if self.key else f"{where}: {self.message}"


class LinedDict(dict):
    """A mapping that knows its file and the line of each key (1-based)."""

    file: str = ""
    line: int = 0
    key_lines: dict[Any, int]

    def line_of(self, key: Any) -> int:
        return self.key_lines.get(key, self.line)


class LinedList(list):
    """A sequence that knows its file and the line of each item (1-based)."""

    file: str = ""
    line: int = 0
    item_lines: list[int]


class _Loader(yaml.SafeLoader):
    """SafeLoader that refuses deep nesting while composing (before Python recursion runs out)."""

    _depth = 0

    def compose_node(self, parent: Any, index: Any) -> Any:
        if self.check_event(yaml.AliasEvent):
            return super().compose_node(parent, index)
        self._depth += 1
        try:
            if self._depth > MAX_DEPTH:
                mark = self.peek_event().start_mark
                raise GraphError(self.name, mark.line + 1, "", f"nested deeper than {MAX_DEPTH} levels")
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1


def _expanded_size(root: yaml.Node) -> int:
    """Values in the document with every alias expanded: linear in the composed nodes (memoised)."""
    sizes: dict[int, int] = {}
    order: list[yaml.Node] = []
    stack, seen = [root], set()
    while stack:  # post-order without recursion
        node = stack.pop()
        if id(node) in seen:
            continue
        seen.add(id(node))
        order.append(node)
        if isinstance(node, yaml.SequenceNode):
            stack.extend(node.value)
        elif isinstance(node, yaml.MappingNode):
            stack.extend(v for kv in node.value for v in kv)
    for node in reversed(order):
        if isinstance(node, yaml.SequenceNode):
            children = node.value
        elif isinstance(node, yaml.MappingNode):
            children = [v for kv in node.value for v in kv]
        else:
            children = []
        sizes[id(node)] = min(1 + sum(sizes.get(id(c), 1) for c in children), MAX_NODES + 1)
    return sizes[id(root)]


def _check_flow_depth(path: Path, text: str) -> None:
    """Refuse bracket nesting beyond MAX_DEPTH before the YAML scanner walks it (it slows down with
    depth). Brackets inside quoted strings count too: no real file has 64 of them open."""
    data = np.frombuffer(text.encode(), np.uint8)
    step = np.zeros(len(data), np.int32)
    step[(data == ord("[")) | (data == ord("{"))] = 1
    step[(data == ord("]")) | (data == ord("}"))] = -1
    depth = np.cumsum(step)
    if len(depth) and depth.max() > MAX_DEPTH:
        at = int(np.argmax(depth > MAX_DEPTH))
        raise GraphError(path, int((data[:at] == ord("\n")).sum()) + 1, "", f"nested deeper than {MAX_DEPTH} levels")


def read_text_file(path: Path, what: str = "file") -> str:
    """The UTF-8 text of a regular file of at most MAX_FILE_BYTES; GraphError (one line) otherwise.

    Checked before reading: a FIFO or device would block or never end, a huge file would be read
    whole; then a NUL byte or invalid UTF-8 says it is binary, not text.
    """
    try:
        st = os.stat(path)
    except FileNotFoundError:
        raise GraphError(path, None, "", "file not found") from None
    except OSError as exc:
        raise GraphError(path, None, "", f"cannot read ({exc.strerror})") from None
    if not stat.S_ISREG(st.st_mode):
        kind = ("a directory" if stat.S_ISDIR(st.st_mode) else "a FIFO" if stat.S_ISFIFO(st.st_mode)
                else "a socket" if stat.S_ISSOCK(st.st_mode) else "a device")
        raise GraphError(path, None, "", f"is {kind}, not a regular {what}")
    if st.st_size > MAX_FILE_BYTES:
        raise GraphError(path, None, "", f"is {st.st_size} bytes; a {what} may have at most {MAX_FILE_BYTES} "
                         "(1 MiB)")
    try:
        with open(path, "rb") as f:
            data = f.read(MAX_FILE_BYTES + 1)
    except OSError as exc:
        raise GraphError(path, None, "", f"cannot read ({exc.strerror})") from None
    if len(data) > MAX_FILE_BYTES:
        raise GraphError(path, None, "", f"is larger than the {MAX_FILE_BYTES} bytes a {what} may have")
    if b"\0" in data:
        raise GraphError(path, data[:data.index(b"\0")].count(b"\n") + 1, "", f"binary data (a NUL byte), not a YAML {what}")
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data[:exc.start].count(b"\n") + 1
        raise GraphError(path, line, "", f"binary data (not UTF-8 text at byte {exc.start}), not a YAML {what}") from None


def _construct_mapping(loader: _Loader, node: yaml.MappingNode) -> LinedDict:
    loader.flatten_mapping(node)
    out = LinedDict()
    out.file = loader.name
    out.line = node.start_mark.line + 1
    out.key_lines = {}
    for key_node, value_node in node.value:
        key = loader.construct_object(key_node, deep=True)
        if key in out:
            raise GraphError(loader.name, key_node.start_mark.line + 1, str(key), "key appears twice")
        out[key] = loader.construct_object(value_node, deep=True)
        out.key_lines[key] = key_node.start_mark.line + 1
    return out


def _construct_sequence(loader: _Loader, node: yaml.SequenceNode) -> LinedList:
    out = LinedList(loader.construct_object(child, deep=True) for child in node.value)
    out.file = loader.name
    out.line = node.start_mark.line + 1
    out.item_lines = [child.start_mark.line + 1 for child in node.value]
    return out


_Loader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _construct_mapping)
_Loader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_SEQUENCE_TAG, _construct_sequence)


def load_yaml_file(path: str | Path) -> Any:
    """Parse ``path``; syntax errors, binary, huge, non-regular, deeply nested or alias-bomb files
    become GraphError with the file (and line where there is one)."""
    path = Path(path)
    text = read_text_file(path)
    _check_flow_depth(path, text)
    loader = _Loader(text)
    loader.name = str(path)
    try:
        node = loader.get_single_node()
        if node is None:
            return None
        if _expanded_size(node) > MAX_NODES:
            raise GraphError(path, None, "", f"expands to more than {MAX_NODES} values (aliases): refused")
        return loader.construct_document(node)
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        line = mark.line + 1 if mark else None
        raise GraphError(path, line, "", f"YAML syntax error: {exc.problem or exc.context}") from None
    except yaml.YAMLError as exc:
        raise GraphError(path, None, "", f"YAML error: {str(exc).splitlines()[0] if str(exc) else exc}") from None
    except RecursionError:
        raise GraphError(path, None, "", "nested too deeply") from None
    finally:
        loader.dispose()


def parse_value(text: str) -> Any:
    """A command-line ``name:=value`` value typed as YAML would type it (1.5 -> float)."""
    try:
        return yaml.safe_load(text) if text.strip() else ""
    except yaml.YAMLError:
        return text
