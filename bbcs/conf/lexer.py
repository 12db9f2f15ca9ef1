"""Split .conf text into tokens with their line and column.

Separators are those of the original CBBCSParser (004 §5.2.2.1): whitespace, end of line and
``: { } [ ] ( ) =``; ``#`` discards the rest of its line. Two additions: ``"..."`` quotes a value that holds
separators (a Zenoh endpoint ``"tcp/10.0.0.1:7447"``), and inside a list a comma also separates. Every
pattern below is a single character class, so scanning is linear whatever the input.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from typing import NamedTuple

from bbcs.conf.errors import ConfError

PUNCTUATION = frozenset(":={}[]()")
OPENERS = {"[": "]", "(": ")"}

_BLANK = re.compile(r"[^\S\r\n]+")
_TO_EOL = re.compile(r"[^\r\n]*")
_QUOTED = re.compile(r'[^"\r\n]*')
_WORD = re.compile(r'[^\s:={}\[\]()#"]+')
_WORD_IN_LIST = re.compile(r'[^\s:={}\[\]()#",]+')


class Token(NamedTuple):
    """``kind`` is ``word``, ``string``, ``eof`` or the punctuation character itself."""

    kind: str
    text: str
    line: int
    column: int

    def describe(self) -> str:
        if self.kind == "eof":
            return "end of file"
        if self.kind == "string":
            return f'quoted value "{self.text}"'
        return repr(self.text)


def tokenize(text: str, path: str = "<string>") -> Iterator[Token]:
    """Yield the tokens of ``text`` lazily, so an early syntax error is reported before a later one."""
    i = 0
    n = len(text)
    line = 1
    line_start = 0
    depth = 0  # open list brackets: decides whether a comma separates
    while i < n:
        c = text[i]
        if c == "\n" or c == "\r":
            i += 2 if c == "\r" and i + 1 < n and text[i + 1] == "\n" else 1
            line += 1
            line_start = i
            continue
        if c.isspace():
            i = _BLANK.match(text, i).end()
            continue
        if c == "#":
            i = _TO_EOL.match(text, i).end()
            continue
        column = i - line_start + 1
        if c in PUNCTUATION:
            if c in OPENERS:
                depth += 1
            elif (c == "]" or c == ")") and depth:
                depth -= 1
            yield Token(c, c, line, column)
            i += 1
        elif c == "," and depth:
            yield Token(",", c, line, column)
            i += 1
        elif c == '"':
            end = _QUOTED.match(text, i + 1).end()
            if end >= n or text[end] != '"':
                raise ConfError("unterminated quoted value: the closing '\"' must be on the same line",
                                path=path, line=line, column=column)
            yield Token("string", text[i + 1:end], line, column)
            i = end + 1
        else:
            end = (_WORD_IN_LIST if depth else _WORD).match(text, i).end()
            yield Token("word", text[i:end], line, column)
            i = end
    yield Token("eof", "", line, n - line_start + 1)
