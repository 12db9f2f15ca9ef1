"""The one error a .conf file can produce: where it is and what is wrong."""

from __future__ import annotations

from bbcs.errors import BbcsError


class ConfError(BbcsError):
    """A .conf file is unreadable, malformed or does not fit the struct asked for.

    ``str()`` reads like a compiler message, ``uav1.conf:12:5: expected '}' ...``, so an operator can jump
    straight to the spot; ``line``/``column`` are 1-based and ``None`` when the error has no single place
    (a missing file, a missing required key).
    """

    def __init__(self, message: str, *, path: str = "<string>", line: int | None = None,
                 column: int | None = None) -> None:
        self.message = message
        self.path = path
        self.line = line
        self.column = column
        super().__init__(self.__str__())

    def __str__(self) -> str:
        where = self.path
        if self.line is not None:
            where += f":{self.line}"
            if self.column is not None:
                where += f":{self.column}"
        return f"{where}: {self.message}"

    def __reduce__(self):  # keep pickling (multiprocessing) working with keyword-only arguments
        return (_rebuild, (self.message, self.path, self.line, self.column))


def _rebuild(message: str, path: str, line: int | None, column: int | None) -> ConfError:
    return ConfError(message, path=path, line=line, column=column)
