"""Where a mission's text comes from: bounded reads of regular files, and the
YAML 1.2 core schema the format claims.

- ``read_regular(path, limit)`` reads a regular file of at most ``limit``
  bytes; a device (``/dev/zero``), a FIFO or a directory is refused before it
  is opened (a FIFO would block, a device would never end), and at most
  ``limit + 1`` bytes are ever read.
- ``compose(text)`` is ``yaml.compose`` with the safe loader changed in two
  ways. Plain scalars are resolved by the YAML 1.2 core schema (PyYAML
  implements YAML 1.1): ``1:30`` is the string "1:30", not 90 (sexagesimal);
  ``yes``/``no``/``on``/``off`` are strings, not booleans; ``1e3`` is a float;
  ``0o17`` is octal; ``1_000`` and ``0b101`` are strings. And nesting is bounded:
  a collection more than ``MAX_NESTING`` levels deep is a YAML error at its
  line, raised by the scanner for flow collections (PyYAML's scanner is
  quadratic in the flow depth) and by the composer for block ones (PyYAML
  composes recursively, so 5,000 ``[`` used to end in a RecursionError).
"""

from __future__ import annotations

import os
import re
import stat
from pathlib import Path
from typing import Any

import yaml
from yaml.composer import ComposerError
from yaml.scanner import ScannerError

__all__ = [
    "KEY_FILE_MAX_BYTES",
    "MAX_NESTING",
    "SIGNING_KEY_BYTES",
    "YAML12Loader",
    "compose",
    "key_file_path",
    "read_regular",
    "signing_key_bytes",
]

#: Deepest nesting of lists and mappings in a mission file (the format needs 4).
MAX_NESTING = 64

_TAG = "tag:yaml.org,2002:"
#: MAVLink 2's signing key length (``mavwire.signing``; a test keeps them equal).
SIGNING_KEY_BYTES = 32
#: A key file holds 32 bytes, or 64 hex digits and a newline: anything over this is refused unread.
KEY_FILE_MAX_BYTES = 4096


def read_regular(path: str, limit: int) -> bytes:
    """The bytes of the regular file ``path`` (symbolic links followed).

    Raises ``OSError`` (``strerror`` says why, in words) when it cannot be
    read, is not a regular file, or is larger than ``limit`` bytes."""
    st = os.stat(path)
    if not stat.S_ISREG(st.st_mode):
        kind = "a directory" if stat.S_ISDIR(st.st_mode) else "not a regular file"
        raise OSError(0, f"{kind}; only regular files are read")
    if st.st_size > limit:
        raise OSError(0, f"{st.st_size} bytes is too large (limit {limit})")
    with open(path, "rb") as fh:
        data = fh.read(limit + 1)  # the file may have grown since the stat
    if len(data) > limit:
        raise OSError(0, f"more than {limit} bytes is too large (limit {limit})")
    return data


def key_file_path(mission_source: str, key_file: str) -> str:
    """Where ``mission.signing.key_file`` is: relative to the mission file."""
    path = Path(key_file)
    if not path.is_absolute() and mission_source:
        path = Path(mission_source).parent / path
    return str(path)


def signing_key_bytes(raw: bytes) -> bytes | None:
    """The 32-byte key ``raw`` holds (raw, or 64 hex digits with blanks
    around), or None when it holds neither."""
    if len(raw) == SIGNING_KEY_BYTES:
        return raw
    text = raw.strip()
    if len(text) == 2 * SIGNING_KEY_BYTES:
        try:
            return bytes.fromhex(text.decode("ascii"))
        except (UnicodeDecodeError, ValueError):
            return None
    return None


class YAML12Loader(yaml.SafeLoader):
    """PyYAML's safe loader with YAML 1.2 core-schema resolution of plain
    scalars and bounded nesting (module docstring). Nothing is constructed
    here: the mission loader only composes nodes."""

    yaml_implicit_resolvers: dict[Any, Any] = {}  # noqa: RUF012 (PyYAML's class registry)

    def __init__(self, stream: str) -> None:
        super().__init__(stream)
        self._depth = 0

    def fetch_flow_collection_start(self, TokenClass: Any) -> None:
        # PyYAML's scanner does work proportional to the flow depth for every
        # token: 5,000 "[" took seconds, a megabyte of them would never end.
        if self.flow_level >= MAX_NESTING:
            raise ScannerError(
                None,
                None,
                f"lists and mappings nested more than {MAX_NESTING} levels deep",
                self.get_mark(),
            )
        super().fetch_flow_collection_start(TokenClass)

    def compose_node(self, parent: Any, index: Any) -> Any:
        self._depth += 1
        try:
            if self._depth > MAX_NESTING:
                mark = self.peek_event().start_mark  # type: ignore[no-untyped-call]
                raise ComposerError(
                    None,
                    None,
                    f"lists and mappings nested more than {MAX_NESTING} levels deep",
                    mark,
                )
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1


#: YAML 1.2 core schema (yaml.org/spec/1.2.2, 10.3.2), plus ``<<`` so that a
#: merge key is recognised (and refused by the format) rather than taken as a name.
_RESOLVERS = (
    ("bool", r"true|True|TRUE|false|False|FALSE", "tTfF"),
    ("int", r"[-+]?[0-9]+|0o[0-7]+|0x[0-9a-fA-F]+", "-+0123456789"),
    (
        "float",
        r"[-+]?(?:\.[0-9]+|[0-9]+(?:\.[0-9]*)?)(?:[eE][-+]?[0-9]+)?"
        r"|[-+]?\.(?:inf|Inf|INF)|\.(?:nan|NaN|NAN)",
        "-+0123456789.",
    ),
    ("null", r"~|null|Null|NULL|", ["~", "n", "N", ""]),
    ("merge", r"<<", "<"),
)
for _name, _pattern, _first in _RESOLVERS:
    YAML12Loader.add_implicit_resolver(_TAG + _name, re.compile(rf"^(?:{_pattern})$"), list(_first))


def compose(text: str) -> yaml.Node | None:
    """The node tree of the single YAML document ``text`` (None if empty).
    ``yaml.YAMLError`` as PyYAML raises it, for the caller to word."""
    loader = YAML12Loader(text)
    try:
        node: yaml.Node | None = loader.get_single_node()
        return node
    finally:
        loader.dispose()
